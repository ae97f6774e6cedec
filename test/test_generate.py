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
"""`physdyn generate`: determinism, resume after interruption, splits, format round trip, bad input."""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from physdyn_ros.cli import main as cli_main
from physdyn_ros.data import SHARD_FIELDS, Dataset, check_disjoint, leave_one_category_out, make_splits, write_npz
from physdyn_ros.data.format import npz_bytes, sha256_file
from physdyn_ros.sim import generate as gen

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module", autouse=True)
def _cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("PHYSDYN_CACHE", str(tmp_path_factory.mktemp("physdyn_cache")))
    yield
    mp.undo()


def params(**kw) -> dict:
    ns = argparse.Namespace(config="generate_tiny", categories=None, num_sims=None, shapes_per_category=None,
                            seed=None, shard_size=None, num_frames=None, friction=None, vary_friction=None,
                            meshes=None, leave_out=None, test_fraction=None, collision=None)
    for k, v in kw.items():
        setattr(ns, k, v)
    return gen.resolve_params(ns)


def shard_digests(out: Path) -> list[str]:
    return [sha256_file(p) for p in sorted((out / "shards").glob("shard_*.npz"))]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The tiny dataset (box + mug, 12 sims, 3 shards) made with one worker."""
    out = tmp_path_factory.mktemp("ref") / "ds"
    gen.generate(out, params(), workers=1, progress=False)
    return out


def test_determinism_across_worker_counts(reference, tmp_path):
    out = tmp_path / "ds"
    gen.generate(out, params(), workers=2, progress=False)
    assert shard_digests(out) == shard_digests(reference)
    assert (out / "manifest.json").read_bytes() == (reference / "manifest.json").read_bytes()
    assert sha256_file(out / "shapes.npz") == sha256_file(reference / "shapes.npz")


def test_format_round_trip(reference):
    m = json.loads((reference / "manifest.json").read_text())
    assert m["format"] == "physdyn-dataset" and m["version"] == 1 and m["complete"]
    assert m["dt"] == pytest.approx(1 / 15) and m["num_frames"] == 61 and m["num_points"] == 1024
    assert [s["index"] for s in m["shapes"]] == list(range(6))
    assert m["counts"]["sims"] == 12 and len(m["shards"]) == 3
    for e in m["shards"]:
        assert e["sha256"] == sha256_file(reference / e["file"]) and isinstance(e["seed"], int)
    ds = Dataset(reference)
    assert ds.points.shape == (6, 1024, 3) and ds.points.dtype == np.float32
    data = ds.load(verify=True)
    assert len(ds) == 12
    for name, (dtype, trailing) in SHARD_FIELDS.items():
        shape = (12,) + tuple(61 if d == "T" else d for d in trailing)
        assert data[name].dtype == np.dtype(dtype) and data[name].shape == shape, name
    np.testing.assert_array_equal(data["sim_index"], np.arange(12))
    np.testing.assert_array_equal(data["shape_index"], np.arange(12) % 6)
    # Canonical clouds are centred at the COM and scale into the simulated object.
    for split in ("train", "val", "test"):
        part = ds.load(split, fields=["shape_index", "pos"])
        assert set(part["shape_index"].tolist()) <= set(ds.shape_indices(split).tolist())
    assert sum(len(ds.load(s, fields=["length"])["length"]) for s in ("train", "val", "test")) == 12
    # Frame 0 is just after the impulse: the object moves.
    assert np.all(np.linalg.norm(data["lin_vel"][:, 0], axis=1) > 0.05)
    assert np.all(data["toppled"][np.arange(12), -1] == (data["topple_index"] >= 0))
    with pytest.raises(ValueError, match="unknown fields"):
        ds.load(fields=["nope"])


def test_npz_writer_is_byte_deterministic(tmp_path):
    arrays = {"a": np.arange(5, dtype=np.int32), "b": np.ones((2, 3), np.float32)}
    d1 = write_npz(tmp_path / "x.npz", arrays)
    time.sleep(1.1)  # zip timestamps have 2 s resolution; ours are fixed
    d2 = write_npz(tmp_path / "y.npz", arrays)
    assert d1 == d2 == sha256_file(tmp_path / "x.npz")
    assert npz_bytes(arrays) == (tmp_path / "y.npz").read_bytes()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp file left


def test_resume_after_deleted_and_truncated_shards(reference, tmp_path):
    out = tmp_path / "ds"
    gen.generate(out, params(), workers=1, progress=False)
    (out / "shards/shard_00001.npz").unlink()
    data = (out / "shards/shard_00002.npz").read_bytes()
    (out / "shards/shard_00002.npz").write_bytes(data[: len(data) // 2])  # a torn write
    before = (out / "shards/shard_00000.npz").stat().st_mtime_ns
    gen.generate(out, params(), workers=2, progress=False)
    assert shard_digests(out) == shard_digests(reference)
    assert (out / "shards/shard_00000.npz").stat().st_mtime_ns == before  # finished shard skipped
    assert (out / "manifest.json").read_bytes() == (reference / "manifest.json").read_bytes()


def test_kill_mid_run_then_resume(tmp_path):
    # Convex categories only (no V-HACD) and many small shards, so the kill lands mid-run.
    args = ["generate", "--config", "generate_tiny", "--categories", "box,cylinder", "--num-sims", "160",
            "--shard-size", "2", "--workers", "1", "--no-progress"]
    out = tmp_path / "killed"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, "-m", "physdyn_ros.cli", *args, str(out)], env=env, cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 60
        while time.time() < deadline and len(list((out / "shards").glob("shard_*.npz"))) < 3:
            time.sleep(0.02)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    m = json.loads((out / "manifest.json").read_text())
    done = [e for e in m["shards"] if e["sha256"]]
    assert not m["complete"] and 0 < len(done) < len(m["shards"])
    with pytest.raises(ValueError, match="incomplete"):
        Dataset(out)
    partial = Dataset(out, allow_partial=True)
    assert len(partial.load(verify=True)["length"]) == 2 * len(done)
    # Rerun to completion with two workers; compare with an uninterrupted one-worker run.
    p = params(categories="box,cylinder", num_sims=160, shard_size=2)
    gen.generate(out, p, workers=2, progress=False)
    ref = tmp_path / "ref"
    gen.generate(ref, p, workers=1, progress=False)
    assert shard_digests(out) == shard_digests(ref)
    assert Dataset(out).manifest["complete"]


def test_shard_range_then_merge(reference, tmp_path):
    a = tmp_path / "a"
    gen.generate(a, params(), workers=1, shard_range="0:2", progress=False)
    m = json.loads((a / "manifest.json").read_text())
    assert not m["complete"] and [bool(e["sha256"]) for e in m["shards"]] == [True, True, False]
    b = tmp_path / "b"
    gen.generate(b, params(), workers=1, shard_range="2:", progress=False)
    # "Copy the shards together" then rerun the full command: the foreign shard is adopted, not recomputed.
    os.replace(b / "shards/shard_00002.npz", a / "shards/shard_00002.npz")
    mtime = (a / "shards/shard_00002.npz").stat().st_mtime_ns
    gen.generate(a, params(), workers=1, progress=False)
    assert (a / "shards/shard_00002.npz").stat().st_mtime_ns == mtime
    assert shard_digests(a) == shard_digests(reference)
    with pytest.raises(ValueError, match="selects no shard"):
        gen.generate(tmp_path / "c", params(), workers=1, shard_range="5:9", progress=False)


def test_other_parameters_are_refused(reference, tmp_path):
    with pytest.raises(ValueError, match="other parameters.*seed"):
        gen.generate(reference, params(seed=1), workers=1, progress=False)
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="not empty"):
        gen.generate(junk, params(), workers=1, progress=False)


@pytest.mark.parametrize("argv, message", [
    (["--categories", "box,chair"], "unknown categories"),
    (["--num-sims", "0"], "num-sims must be a positive integer"),
    (["--shapes-per-category", "-2"], "shapes-per-category must be a positive integer"),
    (["--shard-size", "0"], "shard-size must be a positive integer"),
    (["--num-frames", "30"], "num-frames must be >= 61"),
    (["--friction", "-1"], "friction"),
    (["--config", "no_such_config"], "config file not found"),
    (["--leave-out", "speaker"], "leave-out"),
    (["--mesh", "/nonexistent/mesh.obj"], "mesh file not found"),
    (["--shard-range", "x:y"], "shard-range"),
])
def test_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    base = [] if "--config" in argv else ["--config", "generate_tiny"]
    code = cli_main(["generate", *base, *argv, "--no-progress", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and message in err and err.count("\n") == 1, err
    assert not out.exists()


def test_unreadable_mesh_is_refused(tmp_path, capsys):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")  # one triangle: no volume
    out = tmp_path / "out"
    assert cli_main(["generate", "--config", "generate_tiny", "--mesh", str(bad), str(out)]) == 2
    assert "watertight" in capsys.readouterr().err and not out.exists()


def test_user_meshes_and_pybullet_data_category(tmp_path):
    v = np.array([[x, y, z] for x in (0, .1) for y in (0, .08) for z in (0, .12)])
    from physdyn_ros.shapes import convex_hull

    hv, hf = convex_hull(v)
    mesh = tmp_path / "brick.obj"
    mesh.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in hv) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in hf))
    p = params(categories="box,pybullet_data", meshes=[str(mesh)], num_sims=8, shard_size=8, shapes_per_category=2)
    out = tmp_path / "ds"
    gen.generate(out, p, workers=1, progress=False)
    ds = Dataset(out)
    cats = {s["id"]: s["category"] for s in ds.shapes}
    assert sorted(set(cats.values())) == ["box", "custom", "pybullet_data"]
    pyb = {i for i, c in cats.items() if c == "pybullet_data"}
    assert pyb and pyb <= set(ds.splits["test"])  # never trained on
    assert not pyb & (set(ds.splits["train"]) | set(ds.splits["val"]))


def test_splits_are_object_level():
    shapes = [{"id": f"{c}_{i:04d}", "category": c} for c in ("box", "mug", "pybullet_data") for i in range(50)]
    s = make_splits(shapes, seed=0, test_fraction=0.2, val_fraction=0.1)
    check_disjoint(s)
    assert sorted(sum(s.values(), [])) == sorted(x["id"] for x in shapes)
    box_test = [i for i in s["test"] if i.startswith("box")]
    box_val = [i for i in s["val"] if i.startswith("box")]
    assert len(box_test) == 10 and len(box_val) == 4  # val = 10 % of the 40 training shapes
    assert all(i in s["test"] for i in (x["id"] for x in shapes if x["category"] == "pybullet_data"))
    assert make_splits(shapes, seed=0) == s and make_splits(shapes, seed=1) != s
    loo = leave_one_category_out(shapes, "mug")
    check_disjoint(loo)
    assert {i for i in loo["test"] if i.startswith("mug")} == {x["id"] for x in shapes if x["category"] == "mug"}
    assert not [i for i in loo["train"] + loo["val"] if not i.startswith("box")]
    with pytest.raises(ValueError, match="not in the dataset"):
        make_splits(shapes, leave_out=["chair"])
    with pytest.raises(ValueError, match="both"):
        check_disjoint({"train": ["a"], "test": ["a"]})


def test_broad_config_resolves():
    """config/generate_broad2.yaml: every category (the paper's six and the families) but the three no config
    holds, thousands of shapes, whole families held out, the parts collision and thin-object scale limits;
    generate_broad.yaml the same without the roller family (the world the shipped model was trained on)."""
    from physdyn_ros.shapes import ALL_CATEGORIES, FAMILIES, HELD_OUT_FAMILIES

    configs = {name: params(config=name) for name in ("generate_broad", "generate_broad2")}
    later = ("tool", "topheavy", "rocker")  # families no config holds (docs/architecture.md)
    assert set(later) <= set(FAMILIES)
    worlds = [c for c in ALL_CATEGORIES if c not in later]
    for name, categories in (("generate_broad", [c for c in worlds if c != "roller"]),  # the shipped
                             ("generate_broad2", worlds)):                                # model's world
        p = configs[name]
        assert p["categories"] == categories, name
        assert len(p["categories"]) * p["shapes_per_category"] >= 3000
        assert set(p["leave_out"]) == set(HELD_OUT_FAMILIES) and set(p["leave_out"]) <= set(FAMILIES)
        assert p["sim"]["collision"] == "parts" and p["push"]["size_limits"] == [0.015, 0.45]
        assert gen.test_groups(p)["held_out"] == [c for c in ALL_CATEGORIES if c in HELD_OUT_FAMILIES]
    one, two = ({k: v for k, v in p.items() if k != "categories"} for p in configs.values())
    assert one == two


def test_generate_new_families_with_held_out_family(tmp_path, capsys):
    """A tiny dataset over new families: convex pieces collide without V-HACD, the held-out family is entirely in
    test and reported apart (manifest test_groups and counts, the command's summary)."""
    out = tmp_path / "ds"
    argv = ["generate", str(out), "--config", "generate_tiny", "--categories", "ring,composite,prism,box",
            "--shapes-per-category", "3", "--num-sims", "12", "--shard-size", "6", "--leave-out", "ring",
            "--test-fraction", "0.34", "--workers", "1", "--no-progress"]
    assert cli_main(argv) == 0
    printed = capsys.readouterr().out
    assert "test, held out: 3 shapes, 3 simulations (ring)" in printed
    ds = Dataset(out)
    m = ds.manifest
    assert m["test_groups"] == {"in_category": ["composite", "prism", "box"], "held_out": ["ring"], "test_only": []}
    cats = {s["id"]: s["category"] for s in ds.shapes}
    rings = {i for i, c in cats.items() if c == "ring"}
    assert rings == {i for i in ds.splits["test"] if cats[i] == "ring"} and len(rings) == 3
    assert not rings & (set(ds.splits["train"]) | set(ds.splits["val"]))
    g = m["counts"]["test_groups"]
    assert g["held_out"] == {"categories": ["ring"], "shapes": 3, "sims": 3}
    assert g["in_category"]["shapes"] == 3 and g["in_category"]["sims"] == 3
    assert g["in_category"]["shapes"] + g["held_out"]["shapes"] == m["counts"]["splits"]["test"]["shapes"]
    assert {s["category"]: s["convex"] for s in ds.shapes} == {"ring": False, "composite": False, "prism": True,
                                                                 "box": True}
    data = ds.load()
    assert len(ds) == 12 and np.all(np.isfinite(data["pos"])) and np.all(data["mass"] > 0)
    # The clouds are the families' shapes, centred at the centre of mass.
    from physdyn_ros.shapes import make_procedural

    row = next(s["index"] for s in ds.shapes if s["id"] == "ring_0001")
    np.testing.assert_array_equal(ds.points[row], make_procedural("ring", 1, 0).points)
    # Pieces are written once each into the cache (milliseconds), no V-HACD.
    cache = Path(os.environ["PHYSDYN_CACHE"]) / "vhacd"
    assert len([f for f in cache.glob("*.obj") if f.read_text().startswith("o part_0")]) == 6
