"""`physdyn generate`: simulate random pushes with pybullet and write a dataset (format v1, docs/architecture.md).

Determinism: shapes come from (category, index, seed); shard j's seed is derived from the master seed with
numpy's SeedSequence, and simulation i of shard j draws from default_rng([shard_seed, i]) in a fresh pybullet
world. Shard bytes therefore depend only on the parameters and j, never on the worker count or scheduling.

Resumability: every file is written atomically (temporary name + os.replace) and the manifest is rewritten
after each finished shard, so an interruption (Ctrl-C, kill -9) loses at most the shards in progress. Rerunning
the same command verifies finished shards (sha256 and simulation count) and only computes the missing ones.
`--shard-range A:B` lets several machines share one dataset: each runs the same command with its own range,
then the shard files are copied together and the full command is rerun once (it adopts valid shards).
"""
from __future__ import annotations

import argparse
import fcntl
import json
import os
import time
from contextlib import contextmanager
from dataclasses import fields
from pathlib import Path
from typing import Any, Iterator

#: Parameters that shape the data (compared when resuming). workers / shard_range / progress are not included.
DEFAULTS: dict[str, Any] = {
    "categories": ["box", "cylinder", "bottle", "mug", "trashcan", "speaker"],
    "shapes_per_category": 130,
    "num_sims": 50_000,
    "seed": 0,
    "shard_size": 256,
    "num_frames": 76,
    "friction": 0.5,
    "vary_friction": False,
    "meshes": [],
    "test_fraction": 0.2,
    "val_fraction": 0.1,
    "leave_out": [],
    "pybullet_data_max_random": 60,
    "sim": {},  # overrides of SimConfig fields
    "push": {},  # overrides of PushConfig fields
}
CONFIG_DIR = Path(__file__).resolve().parents[2] / "config"


# ------------------------------------------------------------------------------------------------ arguments
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", metavar="OUT", help="dataset directory to create or resume")
    parser.add_argument("--config", help="YAML generator config (a path, or a name in config/, "
                                         "e.g. generate_combined); command-line options override it")
    parser.add_argument("--categories", help="comma-separated categories: box, cylinder, bottle, mug, trashcan, "
                                             "speaker, the families of physdyn_ros.shapes.FAMILIES (superellipsoid, "
                                             "ring, dumbbell, ...; docs/architecture.md), pybullet_data (test "
                                             "only), custom (--mesh)")
    parser.add_argument("--num-sims", type=int, help="total simulations (all splits)")
    parser.add_argument("--shapes-per-category", type=int, help="distinct shapes per procedural category")
    parser.add_argument("--seed", type=int, help="master seed (shapes, splits, pushes)")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    parser.add_argument("--shard-size", type=int, help="simulations per shard file")
    parser.add_argument("--num-frames", type=int, help="frames per simulation (>= 61; default 76 = 5 s)")
    fr = parser.add_mutually_exclusive_group()
    fr.add_argument("--friction", type=float, help="effective friction coefficient of every simulation")
    fr.add_argument("--vary-friction", action="store_true", default=None,
                    help="draw the friction of each simulation from U(0.35, 0.65)")
    parser.add_argument("--mesh", dest="meshes", action="append", metavar="PATH",
                        help="a user mesh (OBJ/STL/PLY, metres, z up) or a folder of them, added as category "
                             "'custom'; repeat for several")
    parser.add_argument("--leave-out", help="comma-separated categories put entirely in the test split (held "
                                            "out of training; reported apart in the manifest's test_groups)")
    parser.add_argument("--test-fraction", type=float, help="fraction of each category's shapes in test")
    parser.add_argument("--collision", choices=["auto", "hull"],
                        help="auto: convex decomposition for concave shapes; hull: convex hull for all")
    parser.add_argument("--shard-range", "--seed-range", dest="shard_range", metavar="A:B",
                        help="only compute shards A..B-1 (to split one dataset across machines)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _load_yaml(spec: str) -> dict:
    import yaml

    path = Path(spec)
    if not path.is_file():
        named = CONFIG_DIR / (spec if spec.endswith((".yaml", ".yml")) else f"{spec}.yaml")
        if not named.is_file():
            raise ValueError(f"config file not found: {spec}")
        path = named
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ValueError(f"cannot parse config {path}: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"config {path} must be a mapping of options")
    data = {k.replace("-", "_"): v for k, v in data.items()}
    unknown = sorted(set(data) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"config {path}: unknown options {unknown}; known: {sorted(DEFAULTS)}")
    return data


def _csv(value: str | list | None) -> list[str] | None:
    if value is None:
        return None
    items = value if isinstance(value, list) else str(value).split(",")
    return [str(x).strip() for x in items if str(x).strip()]


def _expand_meshes(items: list[str]) -> list[str]:
    from ..shapes.meshes import MESH_SUFFIXES

    out = []
    for item in items:
        path = Path(item).expanduser().resolve()
        if path.is_dir():
            found = sorted(str(f) for f in path.iterdir() if f.suffix.lower() in MESH_SUFFIXES)
            if not found:
                raise ValueError(f"mesh folder {path} holds no {'/'.join(MESH_SUFFIXES)} files")
            out += found
        else:
            out.append(str(path))
    return out


def resolve_params(args: argparse.Namespace) -> dict[str, Any]:
    """Defaults <- YAML config <- command line, validated. Raises ValueError on bad input."""
    from ..shapes import ALL_CATEGORIES, PYBULLET_DATA_CATEGORY
    from .push import PushConfig
    from .simulator import SimConfig

    p = json.loads(json.dumps(DEFAULTS))
    if getattr(args, "config", None):
        p.update(_load_yaml(args.config))
    cli = {"categories": _csv(getattr(args, "categories", None)), "num_sims": getattr(args, "num_sims", None),
           "shapes_per_category": getattr(args, "shapes_per_category", None), "seed": getattr(args, "seed", None),
           "shard_size": getattr(args, "shard_size", None), "num_frames": getattr(args, "num_frames", None),
           "friction": getattr(args, "friction", None), "meshes": getattr(args, "meshes", None),
           "leave_out": _csv(getattr(args, "leave_out", None)),
           "test_fraction": getattr(args, "test_fraction", None)}
    p.update({k: v for k, v in cli.items() if v is not None})
    if getattr(args, "vary_friction", None):
        p["vary_friction"] = True
    if getattr(args, "friction", None) is not None:
        p["vary_friction"] = False
    if getattr(args, "collision", None):
        p["sim"] = dict(p["sim"], collision=args.collision)
    p["categories"] = _csv(p["categories"]) or []
    p["leave_out"] = _csv(p["leave_out"]) or []
    p["meshes"] = _expand_meshes(p["meshes"] or [])
    if p["meshes"] and "custom" not in p["categories"]:
        p["categories"].append("custom")

    known = set(ALL_CATEGORIES) | {PYBULLET_DATA_CATEGORY, "custom"}
    if not p["categories"]:
        raise ValueError("no categories given")
    bad = [c for c in p["categories"] if c not in known]
    if bad:
        raise ValueError(f"unknown categories {bad}; known: {', '.join(sorted(known))}")
    if len(set(p["categories"])) != len(p["categories"]):
        raise ValueError(f"duplicate categories in {p['categories']}")
    if "custom" in p["categories"] and not p["meshes"]:
        raise ValueError("category 'custom' needs --mesh")
    for key in ("num_sims", "shapes_per_category", "shard_size", "num_frames", "pybullet_data_max_random"):
        if not isinstance(p[key], int) or isinstance(p[key], bool) or p[key] <= 0:
            raise ValueError(f"{key.replace('_', '-')} must be a positive integer, got {p[key]!r}")
    if p["num_frames"] < 61:
        raise ValueError(f"num-frames must be >= 61 (4 s roll-outs), got {p['num_frames']}")
    if not isinstance(p["seed"], int) or p["seed"] < 0:
        raise ValueError(f"seed must be a non-negative integer, got {p['seed']!r}")
    if not 0 < float(p["friction"]) <= 2:
        raise ValueError(f"friction must be in (0, 2], got {p['friction']}")
    p["friction"] = float(p["friction"])
    if not 0 <= float(p["test_fraction"]) < 1 or not 0 <= float(p["val_fraction"]) < 1:
        raise ValueError("test-fraction and val-fraction must be in [0, 1)")
    bad = [c for c in p["leave_out"] if c not in p["categories"]]
    if bad:
        raise ValueError(f"leave-out categories {bad} are not among the generated categories")
    for key, cls in (("sim", SimConfig), ("push", PushConfig)):
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(p[key]) - names)
        if unknown:
            raise ValueError(f"unknown {key} options {unknown}; known: {sorted(names)}")
    p["sim"].pop("vhacd_cache_dir", None)  # a path on this machine, not a data parameter
    sim_cfg = SimConfig(**{**p["sim"], "friction": p["friction"]})  # validates
    push_cfg = PushConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in p["push"].items()})
    p["sim"] = {k: v for k, v in sim_cfg.to_dict().items() if k != "vhacd_cache_dir"}
    p["push"] = {k: list(v) if isinstance(v, tuple) else v for k, v in push_cfg.to_dict().items()}
    return p


def parse_range(spec: str | None, num_shards: int) -> range:
    if spec is None:
        return range(num_shards)
    try:
        a, b = (int(x) if x else None for x in spec.split(":"))
    except ValueError:
        raise ValueError(f"--shard-range must look like A:B (shard indices), got {spec!r}") from None
    a = 0 if a is None else a
    b = num_shards if b is None else min(b, num_shards)
    if a < 0 or a >= b:
        raise ValueError(f"--shard-range {spec!r} selects no shard (the dataset has {num_shards} shards)")
    return range(a, b)


# ---------------------------------------------------------------------------------------------------- planning
def build_shapes(p: dict[str, Any]) -> list:
    """All shapes of the dataset, in manifest order."""
    from ..shapes import PYBULLET_DATA_CATEGORY, generate_shapes, load_mesh, pybullet_data_shapes

    shapes = []
    for cat in p["categories"]:
        if cat == PYBULLET_DATA_CATEGORY:
            got = pybullet_data_shapes(p["shapes_per_category"], p["pybullet_data_max_random"])
            if not got:
                raise ValueError("no usable pybullet_data meshes found")
            shapes += got
        elif cat == "custom":
            for i, path in enumerate(p["meshes"]):
                shapes.append(load_mesh(path, name=f"custom_{i:04d}_{Path(path).stem}", category="custom"))
        else:
            shapes += generate_shapes(cat, p["shapes_per_category"], p["seed"])
    names = [s.name for s in shapes]
    if len(set(names)) != len(names):
        raise ValueError("shape names are not unique")
    return shapes


def shard_seed(seed: int, index: int) -> int:
    import numpy as np

    return int(np.random.SeedSequence(entropy=seed, spawn_key=(2, index)).generate_state(1, np.uint64)[0] >> 1)


def plan_shards(p: dict[str, Any]) -> list[dict]:
    n, size = p["num_sims"], p["shard_size"]
    return [{"file": f"shards/shard_{j:05d}.npz", "num_sims": min(size, n - j * size), "seed": shard_seed(p["seed"], j),
             "sha256": None} for j in range((n + size - 1) // size)]


def fingerprint(p: dict[str, Any]) -> str:
    import hashlib

    return hashlib.sha256(json.dumps(p, sort_keys=True).encode()).hexdigest()


# ----------------------------------------------------------------------------------------------- worker side
_W: dict[str, Any] = {}


def _init_worker(shapes: list, p: dict[str, Any], cache_dir: str | None, out: str, child: bool = True) -> None:
    import signal

    if child:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and terminates the pool
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # pool.terminate() must just end the worker
        try:  # Linux: die with the parent (kill -9 of the parent must not leave workers running)
            import ctypes

            ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    _W.update(shapes=shapes, p=p, cache_dir=cache_dir, out=out, sim=None)


def _configs(p: dict[str, Any], cache_dir: str | None):
    from .push import PushConfig
    from .simulator import SimConfig

    sim_cfg = SimConfig(**{**p["sim"], "vhacd_cache_dir": cache_dir})
    push_cfg = PushConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in p["push"].items()})
    return sim_cfg, push_cfg


def _decompose(index: int) -> tuple[int, float]:
    from .simulator import convex_decomposition

    sim_cfg, _ = _configs(_W["p"], _W["cache_dir"])
    t = time.perf_counter()
    convex_decomposition(_W["shapes"][index], sim_cfg)
    return index, time.perf_counter() - t


def simulate_shard(j: int, shapes: list, p: dict[str, Any], cache_dir: str | None = None, sim=None) -> dict:
    """Arrays of shard j (pure function of the parameters and j)."""
    import numpy as np

    from ..data.format import stack_sims
    from .push import simulate_push
    from .simulator import Simulator

    sim_cfg, push_cfg = _configs(p, cache_dir)
    own = sim is None
    sim = Simulator(sim_cfg) if own else sim
    try:
        seed = shard_seed(p["seed"], j)
        first = j * p["shard_size"]
        count = min(p["shard_size"], p["num_sims"] - first)
        sims = []
        for i in range(count):
            k = first + i
            shape_index = k % len(shapes)  # round robin: every shape gets the same number of simulations
            rng = np.random.default_rng([seed, i])
            out = simulate_push(sim, shapes[shape_index], rng, push_cfg, vary_friction=p["vary_friction"],
                                num_frames=p["num_frames"])
            out.update(shape_index=np.int32(shape_index), sim_index=np.int64(k))
            sims.append(out)
        return stack_sims(sims)
    finally:
        if own:
            sim.close()


def _run_shard(j: int) -> tuple[int, str, int]:
    from ..data.format import write_npz
    from .simulator import Simulator

    if _W.get("sim") is None:
        sim_cfg, _ = _configs(_W["p"], _W["cache_dir"])
        _W["sim"] = Simulator(sim_cfg)
    arrays = simulate_shard(j, _W["shapes"], _W["p"], _W["cache_dir"], _W["sim"])
    digest = write_npz(Path(_W["out"]) / f"shards/shard_{j:05d}.npz", arrays)
    return j, digest, len(arrays["shape_index"])


# -------------------------------------------------------------------------------------------------- manifest
@contextmanager
def _locked(out: Path) -> Iterator[None]:
    """Exclusive lock for manifest read-modify-write (several processes may share one OUT)."""
    with open(out / ".lock", "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _read_manifest(out: Path) -> dict | None:
    path = out / "manifest.json"
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError:
        raise ValueError(f"{path} is not valid JSON; move it away to regenerate the dataset here") from None


def _diff(a: dict, b: dict, prefix: str = "") -> list[str]:
    keys = sorted(set(a) | set(b))
    out = []
    for k in keys:
        if isinstance(a.get(k), dict) and isinstance(b.get(k), dict):
            out += _diff(a[k], b[k], f"{prefix}{k}.")
        elif a.get(k) != b.get(k):
            out.append(f"{prefix}{k}: {a.get(k)!r} (existing) != {b.get(k)!r} (requested)")
    return out


def _adopt_shard(path: Path, entry: dict, j: int, p: dict, num_shapes: int) -> str | None:
    """sha256 of an existing shard file if it is a valid, finished shard j of this dataset, else None."""
    import numpy as np

    from ..data.format import check_shard, load_npz, sha256_file

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
    from ..data.splits import TEST_ONLY_CATEGORIES

    cats = list(p["categories"])
    return {"in_category": [c for c in cats if c not in p["leave_out"] and c not in TEST_ONLY_CATEGORIES],
            "held_out": [c for c in cats if c in p["leave_out"] and c not in TEST_ONLY_CATEGORIES],
            "test_only": [c for c in cats if c in TEST_ONLY_CATEGORIES]}


def _counts(out: Path, manifest: dict) -> dict:
    import numpy as np

    from ..data.format import load_npz

    idx, top, length = [], [], []
    for e in manifest["shards"]:
        a = load_npz(out / e["file"])
        idx.append(a["shape_index"])
        top.append(a["topple_index"] >= 0)
        length.append(a["length"])
    idx, top, length = np.concatenate(idx), np.concatenate(top), np.concatenate(length)
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


# ------------------------------------------------------------------------------------------------------- run
def _remove_stale_temps(out: Path, age_s: float = 3600.0) -> None:
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


def generate(out: str | os.PathLike, p: dict[str, Any], workers: int | None = None, shard_range: str | None = None,
             progress: bool = True) -> dict:
    """Generate (or resume) the dataset in `out` with resolved parameters `p`; returns the manifest."""
    import numpy as np

    from ..conventions import DT, NUM_POINTS
    from ..data.format import FORMAT_NAME, FORMAT_VERSION, write_json, write_npz
    from ..data.splits import make_splits

    out = Path(out)
    workers = (os.cpu_count() or 1) if workers is None else workers
    if workers <= 0:
        raise ValueError(f"workers must be positive, got {workers}")
    if out.exists() and not out.is_dir():
        raise ValueError(f"OUT {out} exists and is not a directory")
    existing = _read_manifest(out) if out.is_dir() else None
    if existing is None and out.is_dir() and any(f for f in out.iterdir() if f.name != ".lock"):
        raise ValueError(f"OUT {out} is not empty and holds no dataset manifest; choose a new directory")
    if existing is not None:
        if existing.get("format") != "physdyn-dataset":
            raise ValueError(f"{out}/manifest.json is not a physdyn dataset manifest")
        if existing.get("generator") != p:
            diff = _diff(existing.get("generator", {}), p)
            raise ValueError(f"OUT {out} holds a dataset made with other parameters ({'; '.join(diff[:4])}"
                             f"{' ...' if len(diff) > 4 else ''}); use a new directory or the same parameters")

    # Everything that can fail on bad input happens before anything is written.
    shapes = build_shapes(p)
    plan = plan_shards(p)
    todo_range = parse_range(shard_range, len(plan))
    entries = [{"id": s.name, "category": s.category, "index": i, "convex": s.convex,
                "extents": [round(float(x), 6) for x in s.extents],
                "volume": round(float(s.mass_properties().volume), 9), "params": s.params}
               for i, s in enumerate(shapes)]
    splits = make_splits(entries, seed=p["seed"], test_fraction=p["test_fraction"],
                         val_fraction=p["val_fraction"], leave_out=p["leave_out"])
    for s in shapes:
        s.hull()  # computed here (open3d) so worker processes never touch open3d
    manifest = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "generator": p, "seed": p["seed"], "dt": DT,
                "num_frames": p["num_frames"], "num_points": NUM_POINTS, "shapes": entries, "splits": splits,
                "test_groups": test_groups(p), "shards": plan, "counts": {}, "complete": False}

    out.mkdir(parents=True, exist_ok=True)
    (out / "shards").mkdir(exist_ok=True)
    _remove_stale_temps(out)
    write_npz(out / "shapes.npz", {"points": np.stack([s.points for s in shapes]).astype(np.float32)})
    with _locked(out):
        current = _read_manifest(out)
        if current is not None:
            for mine, theirs in zip(manifest["shards"], current["shards"]):
                mine["sha256"] = theirs.get("sha256")
        # Verify what is on disk: recorded shards by sha256, unrecorded ones by content.
        for j, e in enumerate(manifest["shards"]):
            if j in todo_range or e["sha256"]:
                e["sha256"] = _adopt_shard(out / e["file"], e, j, p, len(shapes))
        write_json(out / "manifest.json", manifest)
    todo = [j for j in todo_range if not manifest["shards"][j]["sha256"]]

    cache_dir = None  # SimConfig's default: $PHYSDYN_CACHE/vhacd or ~/.cache/physdyn_ros/vhacd
    # Convex decompositions of the concave shapes the pending shards use, computed first (in parallel) so that
    # no two workers decompose the same shape at once.
    used: set[int] = set()
    for j in todo:
        k = j * p["shard_size"] + np.arange(manifest["shards"][j]["num_sims"])
        used.update((k % len(shapes)).tolist())
    concave = [i for i in sorted(used) if not shapes[i].convex and p["sim"]["collision"] == "auto"]

    def finished(j: int, digest: str, n: int) -> None:
        with _locked(out):
            current = _read_manifest(out) or manifest
            for mine, theirs in zip(manifest["shards"], current["shards"]):
                if theirs.get("sha256") and not mine["sha256"]:
                    mine["sha256"] = theirs["sha256"]  # finished by a process sharing this OUT
            manifest["shards"][j]["sha256"] = digest
            write_json(out / "manifest.json", manifest)

    total = sum(manifest["shards"][j]["num_sims"] for j in todo)
    with _sigterm_as_interrupt():
        _compute(out, shapes, p, cache_dir, todo, concave, total, workers, progress, finished)

    with _locked(out):
        current = _read_manifest(out) or manifest
        for mine, theirs in zip(manifest["shards"], current["shards"]):
            mine["sha256"] = mine["sha256"] or theirs.get("sha256")
        if all(e["sha256"] for e in manifest["shards"]):
            manifest["complete"] = True
            manifest["counts"] = _counts(out, manifest)
        write_json(out / "manifest.json", manifest)
    return manifest


@contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """`kill PID` stops the generator like Ctrl-C: the pool is terminated, finished shards are kept."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _compute(out: Path, shapes: list, p: dict, cache_dir: str | None, todo: list[int], concave: list[int],
             total: int, workers: int, progress: bool, finished) -> None:
    import multiprocessing as mp

    from tqdm import tqdm

    bar = vbar = None
    if progress and concave:
        vbar = tqdm(total=len(concave), unit="shape", desc="convex decompositions (cached)", dynamic_ncols=True)
    if progress and todo:
        bar = tqdm(total=total, unit="sim", desc=f"generate {out.name}", dynamic_ncols=True)
    try:
        if workers == 1 or len(todo) + len(concave) <= 1:
            _init_worker(shapes, p, cache_dir, str(out), child=False)
            for i in concave:
                _decompose(i)
                if vbar:
                    vbar.update(1)
            for j in todo:
                j, digest, n = _run_shard(j)
                finished(j, digest, n)
                if bar:
                    bar.update(n)
        else:
            ctx = mp.get_context("fork")
            with ctx.Pool(min(workers, max(len(todo), len(concave))), initializer=_init_worker,
                          initargs=(shapes, p, cache_dir, str(out))) as pool:
                for _ in pool.imap_unordered(_decompose, concave):
                    if vbar:
                        vbar.update(1)
                for j, digest, n in pool.imap_unordered(_run_shard, todo):
                    finished(j, digest, n)
                    if bar:
                        bar.update(n)
    finally:
        for b in (vbar, bar):
            if b:
                b.close()
        if _W.get("sim") is not None:
            _W["sim"].close()
            _W["sim"] = None


def run(args: argparse.Namespace) -> int:
    p = resolve_params(args)
    t = time.time()
    manifest = generate(args.out, p, workers=args.workers, shard_range=args.shard_range,
                        progress=not args.no_progress)
    done = sum(e["num_sims"] for e in manifest["shards"] if e["sha256"])
    if manifest["complete"]:
        c = manifest["counts"]
        print(f"dataset {args.out}: {c['sims']} simulations of {c['shapes']} shapes, "
              f"{c['toppled_fraction']:.0%} toppled ({time.time() - t:.0f} s)")
        for group, g in c["test_groups"].items():
            if g["shapes"]:
                print(f"  test, {group.replace('_', ' ')}: {g['shapes']} shapes, {g['sims']} simulations "
                      f"({', '.join(g['categories'])})")
    else:
        print(f"dataset {args.out}: {done}/{p['num_sims']} simulations done; run the command without "
              f"--shard-range (or with the remaining ranges) to finish it")
    return 0
