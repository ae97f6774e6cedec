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
"""The manifest of a dataset being generated: an exclusive lock for its read-modify-write (several processes may
share one OUT), reading it, comparing parameters, adopting shards already on disk (by sha256, or by content when
copied from another machine), the test groups and the final counts, and removing stale temporary files.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator


def fingerprint(p: dict[str, Any]) -> str:
    """sha256 of the resolved parameters (canonical JSON): names a parameter set."""
    return hashlib.sha256(json.dumps(p, sort_keys=True).encode()).hexdigest()


@contextmanager
def locked(out: Path) -> Iterator[None]:
    """Exclusive lock for manifest read-modify-write (several processes may share one OUT)."""
    with open(out / ".lock", "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def read_manifest(out: Path) -> dict | None:
    path = out / "manifest.json"
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError:
        raise ValueError(f"{path} is not valid JSON; move it away to regenerate the dataset here") from None


def diff_params(a: dict, b: dict, prefix: str = "") -> list[str]:
    keys = sorted(set(a) | set(b))
    out = []
    for k in keys:
        if isinstance(a.get(k), dict) and isinstance(b.get(k), dict):
            out += diff_params(a[k], b[k], f"{prefix}{k}.")
        elif a.get(k) != b.get(k):
            out.append(f"{prefix}{k}: {a.get(k)!r} (existing) != {b.get(k)!r} (requested)")
    return out


def adopt_shard(path: Path, entry: dict, j: int, p: dict, num_shapes: int) -> str | None:
    """sha256 of an existing shard file if it is a valid, finished shard j of this dataset, else None."""
    import numpy as np

    from ...data.format import check_shard, load_npz, sha256_file

    if not path.is_file():
        return None
    digest = sha256_file(path)
    if entry.get("sha256"):
        return digest if digest == entry["sha256"] else None
    try:  # not recorded (copied from another machine, or killed between rename and manifest update)
        arrays = load_npz(path)
        n = check_shard(arrays, p["num_frames"], entry["num_sims"], num_shapes)
        k = j * p["shard_size"] + np.arange(n)
        if not (np.array_equal(arrays["sim_index"], k) and np.array_equal(arrays["shape_index"], k % num_shapes)):
            return None
    except Exception:  # noqa: BLE001 - unreadable or inconsistent: recompute it
        return None
    return digest


def test_groups(p: dict[str, Any]) -> dict[str, list[str]]:
    """The categories of the test split by kind: `in_category` (shapes held out of categories that are also
    trained on), `held_out` (the `leave_out` categories: whole categories never trained on, e.g. the held-out
    families) and `test_only` (pybullet_data: never trained on in any dataset)."""
    from ...data.splits import TEST_ONLY_CATEGORIES

    cats = list(p["categories"])
    return {"in_category": [c for c in cats if c not in p["leave_out"] and c not in TEST_ONLY_CATEGORIES],
            "held_out": [c for c in cats if c in p["leave_out"] and c not in TEST_ONLY_CATEGORIES],
            "test_only": [c for c in cats if c in TEST_ONLY_CATEGORIES]}


def dataset_counts(out: Path, manifest: dict) -> dict:
    import numpy as np

    from ...data.format import load_npz

    parts: dict[str, list[np.ndarray]] = {"idx": [], "top": [], "length": []}
    for e in manifest["shards"]:  # one shard in memory at a time
        a = load_npz(out / e["file"])
        parts["idx"].append(a["shape_index"])
        parts["top"].append(a["topple_index"] >= 0)
        parts["length"].append(a["length"])
    idx, top, length = (np.concatenate(parts[k]) for k in ("idx", "top", "length"))
    cat_of = np.array([s["category"] for s in sorted(manifest["shapes"], key=lambda s: s["index"])])
    split_of = {i: name for name, ids in manifest["splits"].items() for i in ids}
    split_arr = np.array([split_of.get(s["id"], "") for s in sorted(manifest["shapes"], key=lambda s: s["index"])])
    per_cat = {}
    for c in dict.fromkeys(cat_of.tolist()):
        m = cat_of[idx] == c
        per_cat[c] = {"shapes": int((cat_of == c).sum()), "sims": int(m.sum()), "toppled": int(top[m].sum())}
    per_split = {s: {"shapes": len(manifest["splits"][s]), "sims": int((split_arr[idx] == s).sum())}
                 for s in manifest["splits"]}
    per_group = {}
    for group, cats in test_groups(manifest["generator"]).items():
        shape_in = (split_arr == "test") & np.isin(cat_of, cats)
        per_group[group] = {"categories": cats, "shapes": int(shape_in.sum()), "sims": int(shape_in[idx].sum())}
    return {"sims": int(len(idx)), "shapes": len(manifest["shapes"]), "shards": len(manifest["shards"]),
            "toppled": int(top.sum()), "toppled_fraction": round(float(top.mean()), 4),
            "mean_length": round(float(length.mean()), 2), "categories": per_cat, "splits": per_split,
            "test_groups": per_group}


def remove_stale_temps(out: Path, age_s: float = 3600.0) -> None:
    """Delete temporary files left by killed writers (hidden *.tmp names; readers never see them). Only old
    ones: a process sharing this OUT may be writing a fresh one right now."""
    now = time.time()
    for folder in (out, out / "shards"):
        for tmp in folder.glob(".*.tmp"):
            try:
                if now - tmp.stat().st_mtime > age_s:
                    tmp.unlink()
            except FileNotFoundError:
                pass
