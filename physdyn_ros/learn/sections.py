"""Config sections as dataclasses: one check that a section names only fields its class has."""
from __future__ import annotations

from dataclasses import fields
from typing import Any, Mapping


def known_keys(cls: type, data: Mapping[str, Any], section: str) -> dict[str, Any]:
    """`data` as a dict, or ValueError naming the keys that are not fields of the dataclass `cls`."""
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"unknown {section} config keys: {unknown} (known: {sorted(known)})")
    return dict(data)
