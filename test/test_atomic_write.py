# Copyright 2026 physdyn_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""The package's one atomic writer (data.format.atomic_path / atomic_write)."""
from __future__ import annotations

import os
import stat

import pytest

from physdyn_ros.data.format import atomic_write


def test_atomic_write_gives_the_mode_of_a_plain_open_and_keeps_the_old_file_on_failure(tmp_path):
    """A written file is readable as open() would make it (mkstemp's 0600 made shipped checkpoints private),
    and a writer that fails leaves the previous file and no temporary behind."""
    plain = tmp_path / "plain"
    plain.write_bytes(b"x")
    target = tmp_path / "out.bin"
    atomic_write(target, lambda fh: fh.write(b"first"))
    assert stat.S_IMODE(os.stat(target).st_mode) == stat.S_IMODE(os.stat(plain).st_mode)

    def broken(fh):
        fh.write(b"half")
        raise RuntimeError("disk gone")

    with pytest.raises(RuntimeError, match="disk gone"):
        atomic_write(target, broken)
    assert target.read_bytes() == b"first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin", "plain"]
