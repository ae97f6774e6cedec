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
"""The package builds the way ROS users build it (colcon), and a broken package stops setup.sh loudly."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from conftest import PYTHON, ROOT

VENV = ROOT / ".venv"
SKIP = shutil.ignore_patterns(".venv", "build", "install", "log", ".git", "__pycache__", "*.egg-info",
                              ".pytest_cache", "runs", "data")


def copy_source(dest: Path) -> Path:
    shutil.copytree(ROOT, dest, ignore=SKIP)
    return dest


def ros_build_env() -> dict[str, str]:
    env = dict(os.environ)
    env["CMAKE_PREFIX_PATH"] = str(VENV)
    env["AMENT_PREFIX_PATH"] = str(VENV)
    env["PATH"] = f"{VENV / 'bin'}:{env['PATH']}"
    return env


@pytest.mark.slow
def test_colcon_build_in_a_workspace(tmp_path):
    ws = tmp_path / "ws"
    copy_source(ws / "src" / "physdyn_ros")
    env = ros_build_env()
    run = subprocess.run(
        [str(VENV / "bin" / "colcon"), "build", "--base-paths", "src",
         "--cmake-args", f"-DPython3_EXECUTABLE={VENV / 'bin' / 'python'}", "-DBUILD_TESTING=OFF"],
        cwd=ws, env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    prefix = ws / "install" / "physdyn_ros"
    site = prefix / "lib" / "python3.11" / "site-packages"
    # ros2 run finds executables here; launch and config files are installed to share/
    for exe in ("perception_node", "predictor_node", "sim_node", "recorder_node", "physdyn"):
        assert os.access(prefix / "lib" / "physdyn_ros" / exe, os.X_OK), exe
    assert (prefix / "share" / "physdyn_ros" / "package.xml").exists()
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "physdyn_ros").exists()
    env["PYTHONPATH"] = str(site)
    env["LD_LIBRARY_PATH"] = f"{prefix / 'lib'}:{env.get('LD_LIBRARY_PATH', '')}"
    check = subprocess.run(
        [PYTHON, "-c", "import physdyn_ros, physdyn_ros.msg, physdyn_ros.srv, physdyn_ros.conventions as c;"
         "from physdyn_ros.msg import PredictedTrajectory; PredictedTrajectory();"
         "print(physdyn_ros.conventions.__file__); print(physdyn_ros.msg.__file__); print(c.DT)"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert check.returncode == 0, check.stderr[-3000:]
    conv_file, msg_file, dt = check.stdout.split()
    assert conv_file.startswith(str(site)) and msg_file.startswith(str(site))
    assert float(dt) == pytest.approx(1 / 15)


def run_setup_on(copy: Path) -> subprocess.CompletedProcess:
    # The copy shares the ready environment; every breakage below stops setup.sh before it installs.
    (copy / ".venv").symlink_to(VENV, target_is_directory=True)
    return subprocess.run(["bash", "setup.sh"], cwd=copy, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
@pytest.mark.parametrize("breakage, failed_step", [
    ("bad_package_xml", "validate package.xml"),
    ("missing_dependency", "configure interfaces"),
    ("broken_interface", "interfaces"),
])
def test_broken_package_stops_setup(tmp_path, breakage, failed_step):
    copy = copy_source(tmp_path / "repo")
    if breakage == "bad_package_xml":
        text = (copy / "package.xml").read_text()
        (copy / "package.xml").write_text(text.replace("<version>0.1.0</version>", "<version>one</version>"))
    elif breakage == "missing_dependency":
        text = (copy / "CMakeLists.txt").read_text()
        (copy / "CMakeLists.txt").write_text(
            text.replace("find_package(nav_msgs REQUIRED)", "find_package(nav_msgs REQUIRED)\n"
                         "find_package(physdyn_no_such_msgs REQUIRED)"))
    else:
        with open(copy / "msg" / "ObjectState.msg", "a") as f:
            f.write("no_such_pkg/NoSuchType broken_field\nthis is not a field\n")
    run = run_setup_on(copy)
    out = run.stdout + run.stderr
    assert run.returncode != 0, out[-3000:]
    assert "setup: FAILED: " in out and failed_step in out.split("setup: FAILED: ")[-1], out[-3000:]
    assert "install interfaces" not in run.stdout.replace("FAILED", ""), "a broken build was installed"
    assert "ready:" not in run.stdout
