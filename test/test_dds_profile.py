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
"""Dense clouds between processes: the shipped Fast DDS profile, and who uses it by default."""
from __future__ import annotations

import ast
import os
import subprocess

from conftest import PYTHON, ROOT
from physdyn_ros.launcher import Suite
from physdyn_ros.suite import DDS_PROFILE_VARS, dds_profile_env

PROFILE = ROOT / "config" / "fastdds.xml"
PEER = ROOT / "test" / "dds_cloud_peer.py"


def dense_clouds_received(env: dict[str, str], count: int = 20, points: int = 100_000) -> tuple[str, str]:
    """(subscriber's last line, publisher's last line) for `count` clouds of `points` points."""
    sub = subprocess.Popen([PYTHON, str(PEER), "sub", str(count), "60"], env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True)
    try:
        assert sub.stdout.readline().strip() == "ready"
        pub = subprocess.run([PYTHON, str(PEER), "pub", str(count), str(points)], env=env, capture_output=True,
                             text=True, timeout=120)
        out, _ = sub.communicate(timeout=90)
    finally:
        sub.kill()
    return out.strip().splitlines()[-1], (pub.stdout.strip().splitlines() or [pub.stderr])[-1]


def test_twenty_100k_point_clouds_all_arrive_with_the_profile():
    """Without the profile 2 to 9 of 20 arrived (Fast DDS's 512 KB shared-memory segment; 1.2 MB per cloud)."""
    env = {k: v for k, v in os.environ.items() if k not in DDS_PROFILE_VARS}
    assert dds_profile_env(env) == str(PROFILE)
    received, sent = dense_clouds_received(env)
    assert sent == "sent 20" and received == "received 20", (sent, received)


def test_the_suite_uses_the_profile_unless_one_is_set():
    bare = {k: v for k, v in os.environ.items() if k not in DDS_PROFILE_VARS}
    suite = Suite(env=bare)
    assert suite.dds_profile == str(PROFILE)
    assert all(suite.env[v] == str(PROFILE) for v in DDS_PROFILE_VARS)
    assert not any(v in bare for v in DDS_PROFILE_VARS)  # the caller's dict is not changed
    mine = dict(bare, FASTDDS_DEFAULT_PROFILES_FILE="/etc/my_profile.xml")
    suite = Suite(env=mine)
    assert suite.dds_profile == "/etc/my_profile.xml" and "FASTRTPS_DEFAULT_PROFILES_FILE" not in suite.env
    assert Suite(env=dict(bare, FASTRTPS_DEFAULT_PROFILES_FILE="")).dds_profile is None  # Fast DDS's defaults


def test_the_launch_file_sets_the_profile():
    tree = ast.parse((ROOT / "launch" / "physdyn.launch.py").read_text())
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)]
    env_set = {c.args[0].value: ast.unparse(c.args[1]) for c in calls
               if ast.unparse(c.func) == "SetEnvironmentVariable"}
    assert env_set == {v: "dds_profile" for v in DDS_PROFILE_VARS}
    arg = next(c for c in calls if ast.unparse(c.func) == "DeclareLaunchArgument" and c.args[0].value == "dds_profile")
    default = ast.unparse(next(k.value for k in arg.keywords if k.arg == "default_value"))
    # the user's variable first (either name), else the installed config/fastdds.xml
    assert default.index("FASTRTPS_DEFAULT_PROFILES_FILE") < default.index("FASTDDS_DEFAULT_PROFILES_FILE")
    assert "default_dds_profile" in default
    assert "'config', 'fastdds.xml'" in (ROOT / "launch" / "physdyn.launch.py").read_text()
    assert "LaunchConfiguration('dds_profile')" in ast.unparse(tree)
