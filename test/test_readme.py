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
"""The README's examples run as shown: its tested command block, its client snippet over DDS, `physdyn info`."""
from __future__ import annotations

import json
import re
import subprocess


from conftest import PYTHON, ROOT
from physdyn_ros.launcher import Suite
from test_nodes_support import tiny_model  # noqa: F401 - fixture

README = (ROOT / "README.md").read_text()


def readme_block(name: str) -> str:
    """The fenced block right after `<!-- tested: name -->`."""
    m = re.search(rf"<!-- tested: {name} -->\n```\w*\n(.*?)```", README, re.S)
    assert m, f"README has no tested block '{name}'"
    return m.group(1)


def test_readme_commands_run_as_shown(tmp_path):
    """A newcomer copies the README's commands as shown: every command of the block (a plan executed in the
    sim among them) exits 0 without a traceback."""
    (tmp_path / ".venv").symlink_to(ROOT / ".venv")  # the commands name .venv/bin/... from the repository root
    commands = [ln for ln in readme_block("commands").splitlines() if ln.strip()]
    assert any("physdyn plan" in c and "--execute" in c for c in commands)
    for cmd in commands:
        run = subprocess.run(cmd, shell=True, cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, f"{cmd}\n{run.stdout[-2000:]}\n{run.stderr[-2000:]}"
        assert "Traceback" not in run.stderr, cmd


def test_readme_client_snippet_talks_to_a_running_predictor(tiny_model, tmp_path):
    snippet = tmp_path / "client.py"
    snippet.write_text(readme_block("client"))
    assert "timeout_sec" in snippet.read_text() and "spin_until_future_complete" in snippet.read_text()
    with Suite(overrides={"predictor": [f"model_path:={tiny_model}"]}, nodes=["predictor"],
               log_dir=tmp_path / "logs") as suite:
        suite.wait_ready(120)
        run = subprocess.run([PYTHON, str(snippet)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert re.search(r"comes to rest at \(-?\d+\.\d{3}, -?\d+\.\d{3}\) m after 60 steps", run.stdout), run.stdout


def test_readme_client_snippet_times_out_without_a_predictor(tmp_path):
    """The snippet never waits forever: with no predictor it exits non-zero with its reason."""
    snippet = tmp_path / "client.py"
    snippet.write_text(readme_block("client").replace("timeout_sec=30.0", "timeout_sec=1.0"))
    run = subprocess.run([PYTHON, str(snippet)], capture_output=True, text=True, timeout=60)
    assert run.returncode != 0 and "predict_trajectory is not available" in run.stderr


def test_info_prints_only_json_and_the_model_id():
    """`physdyn info --json` prints only JSON (nothing pybullet prints at import on stdout) and names the shipped
    model by its id."""
    run = subprocess.run([str(ROOT / ".venv" / "bin" / "physdyn"), "info", "--json"], capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    info = json.loads(run.stdout)  # nothing but JSON on stdout
    assert re.fullmatch(r"[\w.-]+-[0-9a-f]{12}", info["default_model_id"]), info["default_model_id"]
    assert not str(info["pybullet"]).startswith("missing")
    # the shipped topple fusion weights belong to the shipped model
    assert info["topple_fusion"].startswith("default.topple_fusion.json, for " + info["default_model_id"] + ","), \
        info["topple_fusion"]
