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
"""`physdyn up`, the launch file and the params file agree; the launcher and the demo work as processes."""
from __future__ import annotations

import ast
import json
import math
import os
import signal
import subprocess
import time
import uuid
from pathlib import Path

import pytest
import yaml
from rclpy.parameter import Parameter

from conftest import PYTHON, ROOT
from physdyn_ros.launcher import LAUNCH_ARGUMENTS, Suite, node_command
from physdyn_ros.suite import CONFIG_NAME, NODES, known_parameters
from test_nodes_support import tiny_model  # noqa: F401 - fixture

LAUNCH = ROOT / "launch" / "physdyn.launch.py"
CONFIG = ROOT / "config" / CONFIG_NAME
PHYSDYN = str(Path(PYTHON).parent / "physdyn")


def _value(node: ast.AST, consts: dict[str, ast.AST]):
    """A literal, or what a name / LaunchConfiguration / os.path.join call stands for (as a tuple of parts)."""
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.Name) and node.id in consts:
        return _value(consts[node.id], consts)
    if isinstance(node, ast.Call):
        fn = ast.unparse(node.func)
        return (fn,) + tuple(_value(a, consts) for a in node.args)
    if isinstance(node, ast.List):
        return [_value(e, consts) for e in node.elts]
    return ast.unparse(node)


def launch_nodes() -> tuple[list[dict], dict[str, object]]:
    tree = ast.parse(LAUNCH.read_text())
    consts = {t.id: n.value for n in ast.walk(tree) if isinstance(n, ast.Assign)
              for t in n.targets if isinstance(t, ast.Name)}
    nodes, args = [], {}
    for call in (n for n in ast.walk(tree) if isinstance(n, ast.Call)):
        kw = {}
        for k in call.keywords:
            if k.arg is None and isinstance(k.value, ast.Name):  # **common = dict(...): its keywords
                kw.update({kk.arg: _value(kk.value, consts) for kk in consts[k.value.id].keywords})
            else:
                kw[k.arg] = _value(k.value, consts)
        name = ast.unparse(call.func)
        if name in ("Node", "LifecycleNode"):
            nodes.append(dict(kw, action=name))
        elif name == "DeclareLaunchArgument":
            args[_value(call.args[0], consts)] = kw.get("default_value")
    return nodes, args


def test_launch_file_starts_what_the_launcher_starts():
    nodes, args = launch_nodes()
    assert [(n["name"], n["executable"]) for n in nodes] == list(NODES)
    assert {n["package"] for n in nodes} == {"physdyn_ros"}
    # managed nodes: launched as launch_ros LifecycleNode, each wrapped by managed() (configure at start, activate
    # once configured), with autostart off (the launch file drives the transitions, its autostart argument says
    # whether)
    assert {n["action"] for n in nodes} == {"LifecycleNode"}
    text = LAUNCH.read_text()
    assert text.count("*managed(LifecycleNode(") == len(NODES)
    for needed in ("TRANSITION_CONFIGURE", "TRANSITION_ACTIVATE", "start_state='configuring'",
                   "goal_state='inactive'", "IfCondition(LaunchConfiguration('autostart'))"):
        assert needed in text, needed
    assert args["autostart"] == "true"
    # every node gets the same params file, whose default is the installed config/suite.yaml, the launch
    # arguments' use_sim_time, namespace and log level
    for n in nodes:
        assert n["parameters"][0] == ("LaunchConfiguration", "params_file"), n
        assert n["namespace"] == ("LaunchConfiguration", "namespace")
        assert n["ros_arguments"] == ["--log-level", ("LaunchConfiguration", "log_level")]
        assert n["parameters"][1] == [("os.path.join", ("get_package_share_directory", "physdyn_ros"), "config",
                                       "state_source_"), ("LaunchConfiguration", "state_source"), ".yaml"], n
        assert "'use_sim_time': LaunchConfiguration('use_sim_time')" in str(n["parameters"][2])
        assert "'autostart': False" in str(n["parameters"][2])
    assert args["state_source"] == "sim"
    # the launch file's arguments are exactly those `physdyn up` offers
    assert set(args) == set(LAUNCH_ARGUMENTS)
    import argparse

    from physdyn_ros.launcher import add_arguments
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    options = {o for a in parser._actions for o in a.option_strings}
    assert set(LAUNCH_ARGUMENTS.values()) <= options
    assert args["params_file"] == ("os.path.join", ("get_package_share_directory", "physdyn_ros"), "config",
                                   CONFIG_NAME)
    cmake = (ROOT / "CMakeLists.txt").read_text()
    for _, exe in NODES:
        # ros2 run / launch find lib/physdyn_ros/<exe>; it runs the module the launcher runs
        script = ROOT / "scripts" / exe
        assert os.access(script, os.X_OK) and f"scripts/{exe}" in cmake
        assert f"from physdyn_ros.nodes.{exe} import main" in script.read_text()
        assert node_command(exe, CONFIG)[1:3] == ["-m", f"physdyn_ros.nodes.{exe}"]


def _remote_parameters(node_name: str, names: list[str], timeout: float = 20.0) -> dict:
    """Values of a running node's parameters, asked over DDS through its get_parameters service."""
    import rclpy
    from rclpy.parameter import parameter_value_to_python
    from rcl_interfaces.srv import GetParameters

    client_node = rclpy.create_node(f"param_probe_{uuid.uuid4().hex[:6]}")
    try:
        cli = client_node.create_client(GetParameters, f"/{node_name}/get_parameters")
        assert cli.wait_for_service(timeout_sec=timeout), f"{node_name} has no parameter service"
        future = cli.call_async(GetParameters.Request(names=names))
        rclpy.spin_until_future_complete(client_node, future, timeout_sec=timeout)
        assert future.done(), f"{node_name} did not answer get_parameters"
        return dict(zip(names, (parameter_value_to_python(v) for v in future.result().values)))
    finally:
        client_node.destroy_node()


def test_overrides_win_over_the_params_file(rclpy_init, tiny_model, tmp_path):
    """-p overrides win over the params file's node section, and the file's values stay for the rest."""
    overrides = {"sim": ["real_time_factor:=0", "rate:=7.5", "category:=cylinder"],
                 "predictor": [f"model_path:={tiny_model}", "horizon:=30", "plan_time_budget:=1"]}
    with Suite(overrides=overrides, nodes=["sim", "predictor"], log_dir=tmp_path / "logs") as suite:
        suite.wait_ready(150)
        sim = _remote_parameters("sim", ["real_time_factor", "rate", "category", "friction"])
        pred = _remote_parameters("predictor", ["horizon", "plan_time_budget", "max_feature_age"])
    assert sim == {"real_time_factor": 0.0, "rate": 7.5, "category": "cylinder", "friction": 0.5}
    assert pred == {"horizon": 30, "plan_time_budget": 1.0, "max_feature_age": 5.0}
    assert "horizon 30" in (tmp_path / "logs" / "predictor.log").read_text()


def test_unknown_or_malformed_overrides_are_refused(tmp_path):
    with pytest.raises(ValueError, match="node 'predictor' has no parameter 'horizn'"):
        Suite(overrides={"predictor": ["horizn:=30"]})
    with pytest.raises(ValueError, match="use NAME:=VALUE"):
        Suite(overrides={"sim": ["real_time_factor=0"]})
    with pytest.raises(ValueError, match="node 'sim' has no parameter 'model_path'"):
        Suite(overrides={"sim": ["model_path:=x.pt"]})
    run = subprocess.run([PHYSDYN, "up", "--param", "predictor:horizn:=30", "--log-dir", str(tmp_path)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode != 0 and "has no parameter 'horizn'" in run.stderr, run.stdout + run.stderr
    assert not list(tmp_path.iterdir()), "a node was started despite the bad override"


def test_params_file_matches_the_declared_parameters(rclpy_init, tiny_model):
    """Every parameter in config/suite.yaml exists with the right type (rclpy ignores unknown ones silently), for
    every node of the suite's SPECS (each a managed node: its module's ManagedNode subclass)."""
    import importlib

    from physdyn_ros.suite import SPECS
    from physdyn_ros.ros.lifecycle import ManagedNode

    config = yaml.safe_load(CONFIG.read_text())
    assert set(config) == {"/**"} | {f"/**/{n}" for n, _ in NODES}
    shared = config["/**"]["ros__parameters"]
    for spec in SPECS:
        name, module = spec.name, importlib.import_module(f"physdyn_ros.nodes.{spec.executable}")
        classes = [c for c in vars(module).values() if isinstance(c, type) and issubclass(c, ManagedNode)
                   and c.__module__ == module.__name__]
        assert len(classes) == 1, f"{module.__name__}: one managed node class expected, found {classes}"
        node = classes[0](cli_args=["--ros-args", "--params-file", str(CONFIG)],
                          parameter_overrides=[Parameter("model_path", value=str(tiny_model))] if spec.model else [])
        try:
            assert node.get_name() == name and node.state == "active"  # autostart from the params file
            own = config[f"/**/{name}"]["ros__parameters"]
            unknown = sorted(k for k in own if not node.has_parameter(k))
            assert not unknown, f"{name}: parameters in {CONFIG.name} that the node does not declare: {unknown}"
            for key, value in own.items():
                assert node.get_parameter(key).value == value, (name, key)
            if spec.model:
                assert node.has_parameter("model_path")
            # the launcher refuses overrides of any other name: its list must be exactly the node's
            assert set(known_parameters(name)) == set(node._parameters), name
            assert node.get_parameter("table_frame").value == shared["table_frame"]
        finally:
            node.destroy_node()


def _leftovers(marker: str) -> list[int]:
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if marker.encode() in (d / "cmdline").read_bytes():
                    pids.append(int(d.name))
            except OSError:
                pass
    return pids


def test_up_starts_the_suite_and_stops_on_ctrl_c(tiny_model):
    marker = f"leak_{uuid.uuid4().hex[:8]}"
    proc = subprocess.Popen([PHYSDYN, "up", "--model", str(tiny_model), "--real-time-factor", "0",
                             "--param", f"sim:object_id:={marker}"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "all nodes ready" in line:
                break
        assert any("all nodes ready" in ln for ln in lines), "".join(lines)[-3000:]
        assert any(ln.startswith("[predictor]") and "active:" in ln for ln in lines)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, out[-3000:]
    assert not _leftovers(marker), "node processes survived the launcher"


def test_up_fails_when_a_node_cannot_start(tmp_path):
    marker = f"leak_{uuid.uuid4().hex[:8]}"
    run = subprocess.run([PHYSDYN, "up", "--model", str(tmp_path / "missing.pt"), "--param",
                          f"sim:object_id:={marker}"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 1
    assert "exited with code 1 during start-up" in run.stderr, run.stdout[-2000:] + run.stderr[-2000:]
    assert "cannot load model from" in run.stdout  # the node's own reason, forwarded
    time.sleep(0.5)
    assert not _leftovers(marker), "the other nodes were not stopped"


@pytest.mark.slow
def test_demo_short_run(tmp_path, tiny_model):
    out = tmp_path / "demo"
    run = subprocess.run([PHYSDYN, "demo", "--pushes", "2", "--model", str(tiny_model), "--output", str(out),
                          "--horizon", "30"], capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "errors over 2 pushes (a toppled push up to its topple)" in run.stdout
    assert "verdict: " in run.stdout
    assert (out / "demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    results = json.loads((out / "results.json").read_text())
    pushes = results["pushes"]
    assert len(pushes) == 2 and pushes[1]["category"] == "pybullet_data"  # an object the model never saw
    from scipy.spatial.transform import Rotation

    for p in pushes:
        assert len(p["true_xy"]) == 31 and len(p["predicted_xy"]) == 31
        # the reported errors are the distance and the angle between the reported poses
        assert p["position_error_cm"] == pytest.approx(100 * math.dist(p["predicted_final"], p["true_final"]))
        turn = Rotation.from_quat(p["predicted_quat"]).inv() * Rotation.from_quat(p["true_quat"])
        assert p["rotation_error_deg"] == pytest.approx(math.degrees(turn.magnitude()), abs=1e-6)
        assert p["verdict"] in ("GOOD", "FAIR", "POOR") and len(p["outline"]) > 50
        # a toppled push is scored at its last upright frame, an upright one at the end
        assert p["scored_step"] == (p["true_topple_step"] - 1 if p["toppled"] else 30)
    assert {"sim.log", "perception.log", "predictor.log"} <= {f.name for f in (out / "logs").iterdir()}


def test_demo_scores_a_toppled_push_up_to_the_topple():
    """A toppled push is scored at its last upright frame: where the object rolls after tipping over is no
    prediction error (the model predicts the topple, not the roll)."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from physdyn_ros.demo import score, verdict

    n = 31
    true_pos = np.zeros((n, 3))
    true_pos[:, 0] = np.linspace(0, 1.5, n)  # rolls 1.5 m after toppling
    tilt = np.clip(np.arange(n) - 8, 0, None) * 0.3  # upright until step 8, then tips over
    true_q = Rotation.from_rotvec(np.column_stack([np.zeros(n), tilt, np.zeros(n)])).as_quat()
    pred_pos = true_pos.copy()
    pred_pos[:, 0] = np.minimum(true_pos[:, 0], 0.5)  # right until the topple (step 11), then stops
    pred_q = Rotation.identity(n).as_quat()
    s = score(pred_pos, pred_q, true_pos, true_q)
    first_tipped = int(np.argmax(np.degrees(tilt) > 45))
    assert s["true_topple_step"] == first_tipped and s["scored_step"] == first_tipped - 1
    assert s["position_error_cm"] < 1e-9 and s["rotation_error_deg"] < 45.0
    upright = score(pred_pos, pred_q, true_pos, pred_q)
    assert upright["true_topple_step"] == -1 and upright["scored_step"] == n - 1
    assert upright["position_error_cm"] == pytest.approx(100.0)
    assert verdict(1.9, 9.0, True) == "GOOD" and verdict(1.0, 1.0, False) == "POOR"
    assert verdict(4.0, 25.0, True) == "FAIR" and verdict(6.0, 5.0, True) == "POOR"


def test_up_namespace_and_sim_time_reach_the_nodes(rclpy_init, tiny_model, tmp_path):
    """`physdyn up --namespace --use-sim-time --no-sim`, as the launch file's arguments do."""
    proc = subprocess.Popen([PHYSDYN, "up", "--no-sim", "--nodes", "predictor", "--model", str(tiny_model),
                             "--namespace", "robot1", "--use-sim-time", "--log-dir", str(tmp_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        lines = []
        while time.monotonic() < deadline and not any("all nodes ready" in ln for ln in lines):
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
        assert any("all nodes ready" in ln for ln in lines), "".join(lines)[-2000:]
        values = _remote_parameters("robot1/predictor", ["use_sim_time", "horizon"])
        assert values == {"use_sim_time": True, "horizon": 60}
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    assert proc.returncode == 0
    assert sorted(f.name for f in tmp_path.iterdir()) == ["predictor.log"]  # --no-sim: no sim started
    bad = subprocess.run([PHYSDYN, "up", "--namespace", "robot 1"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "is not a ROS namespace" in bad.stderr


def test_state_source_perception_sets_the_nodes_it_concerns():
    """--state-source perception: predictor and pusher read perception's states, the sim renders camera clouds at
    15 Hz; every override names a parameter its node declares (the launcher would refuse it otherwise)."""
    import argparse

    from physdyn_ros.launcher import add_arguments, overrides_from_args

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    o = overrides_from_args(parser.parse_args(["--state-source", "perception"]))
    assert "state_source:=perception" in o["predictor"] and "state_source:=perception" in o["pusher"]
    assert {"cloud_source:=camera", "publish_cloud_rate:=15.0"} <= set(o["sim"])
    assert "plan_whole_cloud:=False" in o["predictor"]  # one camera's view encloses no solid to weigh
    for node, assignments in o.items():
        for a in assignments:
            assert a.split(":=")[0] in known_parameters(node), (node, a)
    # the default applies the sim overlay, as the launch file does: both set state_source, whatever the params
    # file says, and leave the sim's cloud source alone
    default = overrides_from_args(parser.parse_args([]))
    assert "state_source:=sim" in default["predictor"] and "state_source:=sim" in default["pusher"]
    assert not any("cloud_source" in a for a in default["sim"])


def test_the_launch_files_state_source_overlays_name_declared_parameters():
    """config/state_source_<sim|perception>.yaml (the launch file's overlay, choices of its state_source argument):
    every parameter is one its node declares, with a value the node accepts, and both set the predictor's and
    the pusher's state_source to their own name; `physdyn up --state-source perception` applies the same file."""
    from physdyn_ros.suite import parse_overrides, state_source_overlay

    text = LAUNCH.read_text()
    assert "choices=['sim', 'perception']" in text
    for source in ("sim", "perception"):
        overlay = state_source_overlay(source)
        assert overlay["pusher"] == [f"state_source:={source}"]
        assert overlay["predictor"][0] == f"state_source:={source}"
        for node, assignments in overlay.items():
            known = known_parameters(node)
            for name, value in parse_overrides(node, assignments).items():
                assert name in known and type(value) is type(known[name]), (source, node, name, value)
    assert state_source_overlay("perception")["sim"] == ["cloud_source:=camera", "publish_cloud_rate:=15.0"]
    assert state_source_overlay("perception")["predictor"][1:] == ["steps_in:=3", "plan_whole_cloud:=False"]
    assert state_source_overlay("perception")["perception"] == ["voxel_size:=0.005"]
