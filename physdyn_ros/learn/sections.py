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
#: removed part and no value of it changes what this code computes; what it was).
ANY = object()
RETIRED: dict[tuple[str, str], tuple[Any, str]] = {
    ("model", "spin_head"): (False, "the spin head fitted by `physdyn fit-spin`"),
    ("model", "spin_hidden"): (ANY, "the width of the spin head"),
    ("model", "prior_lever"): (False, "the prior's learned contact lever"),
    ("train", "lever_lr_scale"): (ANY, "the learning rate of the prior's learned contact lever"),
    ("train", "start_fraction"): (0.0, "training windows drawn from the impulse"),
    ("loss", "w_cum"): (0.0, "the loss on the pose accumulated over a window"),
    ("loss", "w_spin"): (0.0, "the L1 loss on the spin's change and turn about z"),
    ("loss", "w_spin_sq"): (0.0, "the squared loss on the spin's change and turn about z"),
}


def drop_retired(data: Mapping[str, Any], section: str) -> dict[str, Any]:
    """`data` without the keys of removed options (RETIRED) at their off values; ValueError naming a removed
    option that `data` switches on."""
    out = dict(data)
    for (where, key), (off, what) in RETIRED.items():
        if where != section or key not in out:
            continue
        value = out.pop(key)
        if off is not ANY and value != off:
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
