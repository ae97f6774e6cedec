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
"""Config sections as dataclasses: one check that a section names only fields its class has.

A checkpoint stores the whole config of the code that wrote it, every option included. Options removed since
(never shipped, without a measured benefit for a user) can still appear in it: at the value that left them off,
the key is dropped and the checkpoint loads as before; a config that needs one switched on is refused, naming
the option, since the code it needs is gone (git history keeps it).
"""
from __future__ import annotations

from dataclasses import fields
from typing import Any, Mapping

#: Removed options: (section, key) -> (the value that left it off, or ANY where the key only sized or paced a
#: removed part and no value of it changes what this code computes; what it was; None, or a key of the same
#: section without which any value of it loads: the option mattered only with that one on).
ANY = object()
RETIRED: dict[tuple[str, str], tuple[Any, str, str | None]] = {
    ("model", "spin_head"): (False, "the spin head fitted by `physdyn fit-spin`", None),
    ("model", "spin_hidden"): (ANY, "the width of the spin head", None),
    ("model", "prior_lever"): (False, "the prior's learned contact lever", None),
    # the topple head's inputs: this code computes version 6's (learn/support.py), which the shipped model reads
    ("model", "topple_inputs"): (6, "another version of the topple head's inputs (refit the head: physdyn "
                                    "fit-topple)", "topple_head"),
    ("train", "lever_lr_scale"): (ANY, "the learning rate of the prior's learned contact lever", None),
    ("train", "start_fraction"): (0.0, "training windows drawn from the impulse", None),
    ("loss", "w_cum"): (0.0, "the loss on the pose accumulated over a window", None),
    ("loss", "w_spin"): (0.0, "the L1 loss on the spin's change and turn about z", None),
    ("loss", "w_spin_sq"): (0.0, "the squared loss on the spin's change and turn about z", None),
}


def drop_retired(data: Mapping[str, Any], section: str) -> dict[str, Any]:
    """`data` without the keys of removed options (RETIRED) at their off values; ValueError naming a removed
    option that `data` switches on."""
    out = dict(data)
    for (where, key), (off, what, only_with) in RETIRED.items():
        if where != section or key not in out:
            continue
        value = out.pop(key)
        if off is not ANY and value != off and (only_with is None or out.get(only_with)):
            raise ValueError(f"{section}.{key} = {value!r} needs {what}, which this version of physdyn_ros no "
                             f"longer has (the option was removed; only {section}.{key} = {off!r} loads)")
    return out


def known_keys(cls: type, data: Mapping[str, Any], section: str) -> dict[str, Any]:
    """`data` as a dict without removed options (drop_retired), or ValueError naming the keys that are not
    fields of the dataclass `cls`."""
    data = drop_retired(data, section)
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"unknown {section} config keys: {unknown} (known: {sorted(known)})")
    return data
