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
"""`physdyn <cmd>` with a user's mistake: one line `physdyn <cmd>: error: <reason>` on stderr, exit 2, no traceback.

Every case runs the installed `physdyn` entry point as a subprocess, as a user would. The bag cases cover what
the rosbags reader refuses (a .npy file, garbage .mcap / .db3 files, a folder without metadata.yaml, broken
metadata, an unfinished split); the others pin the one-line errors of the remaining subcommands.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import PYTHON, ROOT

PHYSDYN = str(Path(PYTHON).parent / "physdyn")


def _run_all(cases: dict[str, list[str]], cwd: Path, env: dict | None = None, parallel: int = 3) -> dict:
    """{name: argv} -> {name: (returncode, stdout, stderr)}; a few at a time (the machine may be small)."""
    out = {}
    items = list(cases.items())
    for k in range(0, len(items), parallel):
        procs = {name: subprocess.Popen([PHYSDYN, *argv], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True, env={**os.environ, **(env or {})})
                 for name, argv in items[k:k + parallel]}
        for name, p in procs.items():
            so, se = p.communicate(timeout=240)
            out[name] = (p.returncode, so, se)
    return out


def _assert_one_line_error(name: str, cmd: str, res, *fragments: str) -> None:
    rc, _, err = res
    lines = err.strip().splitlines()
    assert "Traceback" not in err, f"{name}: {err}"
    assert rc == 2, f"{name}: exit {rc}: {err}"
    assert len(lines) == 1 and lines[0].startswith(f"physdyn {cmd}: error: "), f"{name}: {err!r}"
    for f in fragments:
        assert f in lines[0], f"{name}: {f!r} not in {lines[0]!r}"


@pytest.fixture(scope="module")
def junk(tmp_path_factory):
    """Files and folders that are not bags, a good bag, and broken copies of it."""
    from physdyn_ros.bag.types import serialize, typestore
    from physdyn_ros.bag.writer import BagWriter

    d = tmp_path_factory.mktemp("junk")
    np.save(d / "some.npy", np.zeros((10, 3)))
    (d / "empty").mkdir()
    (d / "garbage.mcap").write_bytes(b"this is not an mcap file at all")
    (d / "garbage.db3").write_bytes(os.urandom(200))
    (d / "badyaml").mkdir()
    (d / "badyaml" / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    (d / "otheryaml").mkdir()
    (d / "otheryaml" / "metadata.yaml").write_text("foo: 1\n")
    w = BagWriter(d / "good", split_duration=None, min_free=0)
    w.open()
    tid = w.add_topic("/chatter", "std_msgs/msg/String")
    data = serialize(typestore().types["std_msgs/msg/String"](data="abcd"), "std_msgs/msg/String")
    for i in range(20):
        w.write(tid, 1_000 + i, data)
    w.close()
    whole = (d / "good" / "good_0.mcap").read_bytes()
    (d / "truncated.mcap").write_bytes(whole[:-100])  # as a killed recorder leaves its unfinished split
    (d / "bag_split").mkdir()  # an unfinished split's folder: an .mcap but no metadata.yaml
    (d / "bag_split" / "bag_split.mcap").write_bytes(whole[:-100])
    missing = d / "missing_file"
    missing.mkdir()
    (missing / "metadata.yaml").write_text((d / "good" / "metadata.yaml").read_text())
    return d


def test_bag_commands_refuse_non_bags_in_one_line(junk):
    d = junk
    cases = {
        "report npy": ["report", "some.npy"],
        "replay npy": ["replay", "some.npy", "--delay", "0"],
        "bag2dataset npy": ["bag2dataset", "some.npy", "out_npy"],
        "report empty folder": ["report", "empty"],
        "replay empty folder": ["replay", "empty", "--delay", "0"],
        "bag2dataset empty folder": ["bag2dataset", "empty", "out_empty"],
        "report garbage mcap": ["report", "garbage.mcap"],
        "report garbage db3": ["report", "garbage.db3"],
        "report truncated mcap": ["report", "truncated.mcap"],
        "replay truncated mcap": ["replay", "truncated.mcap", "--delay", "0"],
        "report split folder": ["report", "bag_split"],
        "report bad yaml": ["report", "badyaml"],
        "report other yaml": ["report", "otheryaml"],
        "report missing file": ["report", "missing_file"],
        "report nonexistent": ["report", "nope"],
        "replay nonexistent": ["replay", "nope"],
    }
    res = _run_all(cases, d)
    _assert_one_line_error("report npy", "report", res["report npy"],
                           "some.npy is not a rosbag2 bag", "metadata.yaml", ".mcap")
    _assert_one_line_error("replay npy", "replay", res["replay npy"], "some.npy is not a rosbag2 bag")
    _assert_one_line_error("bag2dataset npy", "bag2dataset", res["bag2dataset npy"], "some.npy is not a rosbag2 bag")
    for cmd in ("report", "replay", "bag2dataset"):
        _assert_one_line_error(f"{cmd} empty folder", cmd, res[f"{cmd} empty folder"],
                               "empty is not a rosbag2 bag", "no metadata.yaml")
    _assert_one_line_error("report garbage mcap", "report", res["report garbage mcap"],
                           "garbage.mcap", "not an MCAP file")
    _assert_one_line_error("report garbage db3", "report", res["report garbage db3"], "garbage.db3")
    for cmd in ("report", "replay"):
        _assert_one_line_error(f"{cmd} truncated mcap", cmd, res[f"{cmd} truncated mcap"],
                               "truncated.mcap", "no footer", "mcap recover")
    _assert_one_line_error("report split folder", "report", res["report split folder"],
                           "bag_split is not a rosbag2 bag", "no metadata.yaml", "bag_split.mcap")
    _assert_one_line_error("report bad yaml", "report", res["report bad yaml"], "badyaml", "metadata.yaml")
    _assert_one_line_error("report other yaml", "report", res["report other yaml"], "otheryaml", "metadata.yaml")
    _assert_one_line_error("report missing file", "report", res["report missing file"], "missing_file", "good_0.mcap")
    for cmd in ("report", "replay"):
        _assert_one_line_error(f"{cmd} nonexistent", cmd, res[f"{cmd} nonexistent"], "nope", "not found")
    assert not (d / "out_npy").exists() and not (d / "out_empty").exists()


def test_other_commands_refuse_bad_input_in_one_line(junk, tmp_path):
    d = junk
    cfg = str(ROOT / "config" / "model_default.yaml")
    cases = {
        "train": ["train", "--config", cfg, "--data", "empty", "--out", str(tmp_path / "run")],
        "train npy data": ["train", "--config", cfg, "--data", "some.npy", "--out", str(tmp_path / "run2")],
        "evaluate": ["evaluate", "--checkpoint", "missing.pt", "--data", "empty", "--out", str(tmp_path / "ev")],
        "evaluate data": ["evaluate", "--checkpoint", "some.npy", "--data", "empty", "--out", str(tmp_path / "ev2")],
        "predict": ["predict", "--cloud", "missing.npy", "--lin-vel", "1", "0", "0", "--ang-vel", "0", "0", "0"],
        "plan": ["plan", "--cloud", "some.npy", "--goal", "0.1", "0", "0", "--model", "missing.pt"],
        "plan ensemble": ["plan", "--cloud", "some.npy", "--goal", "0.1", "0", "0", "--model", "other.pt",
                          "--ensemble", "3"],
        "generate": ["generate", str(tmp_path / "gen"), "--num-sims", "0"],
        "record": ["record", "-o", str(tmp_path / "rec"), "--split-size", "5MB"],
        "record parent": ["record", "-o", str(tmp_path / "no" / "such" / "bag")],
        "replay rate": ["replay", "good", "--rate", "0"],
        "up": ["up", "--config", "missing.yaml"],
        "demo": ["demo", "--model", "missing.pt"],
    }
    res = _run_all(cases, d)
    expect = {
        "train": ("empty is not a dataset",), "train npy data": ("some.npy is not a dataset",),
        "evaluate": ("missing.pt does not exist",), "evaluate data": ("some.npy",),
        "predict": ("missing.npy does not exist",), "plan": ("missing.pt does not exist",),
        "plan ensemble": ("--ensemble: an ensemble of 3: the shipped members belong to the shipped model",),
        "generate": ("num-sims",), "record": ("bad size '5MB'",), "record parent": ("does not exist",),
        "replay rate": ("--rate must be positive",), "up": ("missing.yaml does not exist",),
        "demo": ("missing.pt does not exist",),
    }
    for name, fragments in expect.items():
        _assert_one_line_error(name, name.split()[0], res[name], *fragments)
    assert not (tmp_path / "gen").exists() and not (tmp_path / "rec").exists()


def test_argparse_errors_keep_exit_2_and_no_traceback(junk):
    res = _run_all({"rate": ["replay", "good", "--rate", "fast"], "command": ["frobnicate"]}, junk)
    for name, (rc, _, err) in res.items():
        assert rc == 2 and "Traceback" not in err, err
        assert sum(1 for line in err.splitlines() if ": error: " in line) == 1, err
    assert "physdyn replay: error: argument --rate" in res["rate"][2]


def test_bugs_still_show_a_traceback(tmp_path):
    """An unexpected exception (a bug, not a user's mistake) is not turned into a one-line error."""
    script = (
        "import sys, types\n"
        "from physdyn_ros import cli\n"
        "mod = types.ModuleType('fake_cmd')\n"
        "mod.add_arguments = lambda p: p.add_argument('--kind')\n"
        "def run(args):\n"
        "    raise {'bug': ZeroDivisionError('boom'), 'attr': AttributeError('boom'),\n"
        "           'value': ValueError('bad value given'), 'os': FileNotFoundError(2, 'No such file or directory',\n"
        "           'x.bin')}[args.kind]\n"
        "mod.run = run\n"
        "sys.modules['fake_cmd'] = mod\n"
        "cli.COMMANDS['fake'] = ('fake_cmd', 'test')\n"
        "sys.exit(cli.main(['fake', '--kind', sys.argv[1]]))\n")

    def run(kind, **env):
        return subprocess.run([PYTHON, "-c", script, kind], capture_output=True, text=True, cwd=tmp_path,
                              env={**os.environ, **env}, timeout=60)

    for kind in ("bug", "attr"):
        r = run(kind)
        assert r.returncode == 1 and "Traceback" in r.stderr and "boom" in r.stderr, r.stderr
    r = run("value")
    assert r.returncode == 2 and r.stderr == "physdyn fake: error: bad value given\n", r.stderr
    r = run("os")
    assert r.returncode == 2 and r.stderr == "physdyn fake: error: x.bin: No such file or directory\n", r.stderr
    r = run("value", PHYSDYN_DEBUG="1")  # the traceback of a user error on request
    assert r.returncode == 2 and "Traceback" in r.stderr and "ValueError: bad value given" in r.stderr, r.stderr
    assert r.stderr.strip().splitlines()[-1] == "physdyn fake: error: bad value given", r.stderr


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
