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
"""The predictor node over DDS: topic predictions, the service, and every bad input it must refuse cleanly."""
from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Path
from rclpy.parameter import Parameter
from visualization_msgs.msg import Marker, MarkerArray

from physdyn_ros.msg import ObjectState, PredictedTrajectory, ShapeFeature
from physdyn_ros.nodes.predictor_node import PredictorNode
from physdyn_ros.ros.qos import LATCHED, STATE_QOS
from physdyn_ros.ros.cloud import xyz_to_cloud
from physdyn_ros.ros.convert import ns_to_time, point, time_to_ns, vector3
from physdyn_ros.ros.trajectory import object_state
from physdyn_ros.srv import PlanPush, PredictTrajectory
from test_nodes_support import Spinner, call, tiny_model, wait_for  # noqa: F401 - fixture

T0 = 1_000 * 10**9  # stamps of the scenario, ns
RNG = np.random.default_rng(5)
CLOUD = (RNG.uniform(-1, 1, (600, 3)) * (0.05, 0.03, 0.04) + (0.2, 0.1, 0.04)).astype(np.float32)


class Client:
    """Publishes the predictor's inputs and records its outputs."""

    def __init__(self, rclpy):
        self.node = rclpy.create_node("predictor_client")
        self.features = self.node.create_publisher(ShapeFeature, "shape_feature", LATCHED)
        self.states = self.node.create_publisher(ObjectState, "object_state", STATE_QOS)
        self.observed = self.node.create_publisher(ObjectState, "observed_state", STATE_QOS)
        self.twists = self.node.create_publisher(TwistStamped, "initial_twist", 10)
        self.trajs: list[PredictedTrajectory] = []
        self.paths: list[Path] = []
        self.markers: list[MarkerArray] = []
        self.node.create_subscription(PredictedTrajectory, "predicted_trajectory", self.trajs.append, LATCHED)
        self.node.create_subscription(Path, "predicted_path", self.paths.append, LATCHED)
        self.node.create_subscription(MarkerArray, "predicted_markers", self.markers.append, LATCHED)
        self.srv = self.node.create_client(PredictTrajectory, "predict_trajectory")


def feature_msg(pred, stamp_ns: int = T0, object_id: str = "box", frame: str = "world") -> ShapeFeature:
    """The feature the perception node would publish for CLOUD (same encoder, same fields)."""
    code = pred.encode(CLOUD)
    return ShapeFeature(object_id=object_id, model_id=pred.model_id, feature=code.feature.tolist(),
                        heading=code.heading, centroid=point(code.centroid), half_extents=vector3(code.half_extents),
                        num_points=code.num_points, header=_header(stamp_ns, frame))


def _header(stamp_ns: int, frame: str = "world"):
    from std_msgs.msg import Header

    return Header(frame_id=frame, stamp=ns_to_time(stamp_ns))


def state_msg(stamp_ns: int, pos=(0.2, 0.1, 0.04), yaw=0.0, object_id="box") -> ObjectState:
    return object_state("world", ns_to_time(stamp_ns), object_id, pos, [0, 0, math.sin(yaw / 2), math.cos(yaw / 2)],
                        [0.0] * 3, [0.0] * 3)


def twist_msg(stamp_ns: int = T0, v=(0.4, 0.0, 0.0), w=(0.0, 0.0, 1.0), frame="world") -> TwistStamped:
    msg = TwistStamped(header=_header(stamp_ns, frame))
    msg.twist.linear, msg.twist.angular = vector3(v), vector3(w)
    return msg


@pytest.fixture
def predictor(rclpy_init, tiny_model):
    def make(**params):
        return PredictorNode(parameter_overrides=[Parameter("model_path", value=str(tiny_model))]
                             + [Parameter(k, value=v) for k, v in params.items()])
    return make


def send(client: Client, node: PredictorNode, msg: TwistStamped, expect_prediction: bool) -> None:
    before = (node.predictions, node.rejected)
    client.twists.publish(msg)
    assert wait_for(lambda: (node.predictions, node.rejected) != before, 10), "the twist was never handled"
    assert (node.predictions > before[0]) == expect_prediction, node.last_error


def test_twist_gives_trajectory_path_and_markers(rclpy_init, predictor):
    node = predictor(horizon=45)
    c = Client(rclpy_init)
    with Spinner(node, c.node):
        send(c, node, twist_msg(), expect_prediction=False)  # before any feature
        assert "no shape feature received yet" in node.last_error
        c.features.publish(feature_msg(node.predictor, T0 - 10**9))
        c.states.publish(state_msg(T0 - 10**8, pos=(0.1, 0.2, 0.04)))  # the object at rest before the push
        c.states.publish(state_msg(T0, pos=(0.2, 0.1, 0.04), yaw=0.3))  # the state at the push instant
        assert wait_for(lambda: node._features and node._states.get("box") and len(node._states["box"]) == 2)
        send(c, node, twist_msg(), expect_prediction=True)
        assert wait_for(lambda: c.trajs and c.paths and c.markers, 10)
    traj = c.trajs[-1]
    assert traj.header.frame_id == "world" and time_to_ns(traj.header.stamp) == T0
    assert traj.object_id == "box" and traj.model_id == node.model_id and len(traj.states) == 46
    s0 = traj.states[0]
    assert (s0.pose.position.x, s0.pose.position.y) == pytest.approx((0.2, 0.1))  # pose at the twist's stamp
    assert 2 * math.atan2(s0.pose.orientation.z, s0.pose.orientation.w) == pytest.approx(0.3)
    assert s0.twist.linear.x == pytest.approx(0.4) and s0.twist.angular.z == pytest.approx(1.0)
    assert time_to_ns(traj.states[15].header.stamp) - T0 == pytest.approx(10**9, abs=2)
    assert len(c.paths[-1].poses) == 46 and c.paths[-1].poses[45].pose == traj.states[45].pose
    markers = c.markers[-1].markers
    assert markers[0].action == Marker.DELETEALL and markers[1].type == Marker.LINE_STRIP
    assert [m.id for m in markers[2:]] == [0, 10, 20, 30, 40, 45]


@pytest.mark.parametrize("case, reason", [
    ("nan", "velocity is not finite"),
    ("absurd_v", "exceeds max_linear_speed"),
    ("absurd_w", "exceeds max_angular_speed"),
    ("frame", "initial_twist frame_id 'camera' is not the table frame 'world'"),
    ("stale", "is stale: 12.00 s older than the push"),
    ("other_model", "comes from model 'other-model'"),
    ("no_state", "no object_state of 'box' at or before the push"),
    ("old_state", "latest object_state of 'box' is 3.00 s older than the push"),
    ("unset_stamp", "initial_twist header.stamp is unset (0): stamp the twist"),
    ("absurd_stamp", "are 20.0 days apart: one stamp is absurd or from another clock"),
    ("early_push", "every shape feature of 'box' is newer than the push: the oldest by 9.00 s"),
])
def test_bad_twists_are_refused_with_the_reason(rclpy_init, predictor, case, reason):
    node = predictor(state_wait=0.05)
    c = Client(rclpy_init)
    feature = feature_msg(node.predictor, T0 - 12 * 10**9 if case == "stale" else T0 - 10**9)
    if case == "other_model":
        feature.model_id = "other-model"
    twist = {"nan": twist_msg(v=(math.nan, 0, 0)), "absurd_v": twist_msg(v=(50.0, 0, 0)),
             "absurd_w": twist_msg(w=(0, 0, 500.0)), "frame": twist_msg(frame="camera"),
             "unset_stamp": twist_msg(stamp_ns=0), "absurd_stamp": twist_msg(stamp_ns=T0 + 20 * 86_400 * 10**9 - 10**9),
             "early_push": twist_msg(stamp_ns=T0 - 10 * 10**9)}.get(case, twist_msg())
    with Spinner(node, c.node):
        c.features.publish(feature)
        if case != "no_state":
            c.states.publish(state_msg(T0 - 3 * 10**9 if case == "old_state" else T0))
        assert wait_for(lambda: node._features and (case == "no_state" or node._states))
        send(c, node, twist, expect_prediction=False)
        assert reason in node.last_error, node.last_error
        # the node is still serving: a good push right after is predicted
        c.states.publish(state_msg(T0 + 10**9))
        c.features.publish(feature_msg(node.predictor, T0 + 10**9))
        assert wait_for(lambda: node._features["box"][-1].model_id == node.model_id and node._states.get("box") and
                        time_to_ns(node._states["box"][-1].header.stamp) == T0 + 10**9)
        send(c, node, twist_msg(T0 + 10**9), expect_prediction=True)


def test_steps_in_refines_with_observed_states(rclpy_init, predictor):
    node = predictor(steps_in=3, horizon=30)
    c = Client(rclpy_init)
    with Spinner(node, c.node):
        c.features.publish(feature_msg(node.predictor))
        c.states.publish(state_msg(T0))
        assert wait_for(lambda: node._features and node._states)
        send(c, node, twist_msg(), expect_prediction=True)
        dt = int(1e9 / 15)
        observed = [state_msg(T0 + k * dt, pos=(0.2 + 0.02 * k, 0.1, 0.04)) for k in (1, 2, 3)]
        for k, s in enumerate(observed, 1):  # online adaptation: one corrected trajectory per observed state
            c.observed.publish(s)
            assert wait_for(lambda: any(t.steps_in == k for t in c.trajs), 10), node.last_error
        c.observed.publish(state_msg(T0 + 4 * dt, pos=(0.28, 0.1, 0.04)))  # beyond steps_in: no more
        assert not wait_for(lambda: any(t.steps_in > 3 for t in c.trajs), 0.5)
    assert [t.steps_in for t in c.trajs] == [0, 1, 2, 3]
    refined = next(t for t in c.trajs if t.steps_in == 3)
    assert time_to_ns(refined.header.stamp) == T0 and len(refined.states) == 31
    # observed frames keep their observed poses, and (state_source sim) their twists as given
    assert [s.pose.position.x for s in refined.states[1:4]] == pytest.approx([0.22, 0.24, 0.26])
    assert [s.twist.linear.x for s in refined.states[1:4]] == [0.0, 0.0, 0.0]


def request(**kw) -> PredictTrajectory.Request:
    req = PredictTrajectory.Request()
    req.header.frame_id = kw.pop("frame", "world")
    req.object_id = kw.pop("object_id", "")
    req.horizon = kw.pop("horizon", 0)
    req.include_path = kw.pop("include_path", False)
    req.initial_twist.linear = vector3(kw.pop("v", (0.5, 0.0, 0.0)))
    req.initial_twist.angular = vector3(kw.pop("w", (0.0, 0.0, 0.5)))
    if "cloud" in kw:
        req.cloud = kw.pop("cloud")
    if "orientation" in kw:
        q = kw.pop("orientation")
        req.initial_pose.orientation.x, req.initial_pose.orientation.y = q[0], q[1]
        req.initial_pose.orientation.z, req.initial_pose.orientation.w = q[2], q[3]
    req.initial_pose.position = point(kw.pop("position", (0.2, 0.1, 0.04)))
    assert not kw
    return req


def no_xyz():
    cloud = xyz_to_cloud(CLOUD, "world")
    cloud.fields[2].name = "intensity"
    return cloud


def test_service_answers_good_requests_and_refuses_bad_ones(rclpy_init, predictor):
    node = predictor()
    c = Client(rclpy_init)
    with Spinner(node, c.node):
        res = call(c.srv, request(cloud=xyz_to_cloud(CLOUD, "world"), horizon=30, include_path=True))
        assert res.success, res.message
        assert len(res.trajectory.states) == 31 and len(res.path.poses) == 31
        assert res.path.poses[30].pose == res.trajectory.states[30].pose
        assert not call(c.srv, request(cloud=xyz_to_cloud(CLOUD, "world"), horizon=30)).path.poses  # not asked
        assert res.trajectory.object_id == "cloud" and res.trajectory.model_id == node.model_id
        assert res.trajectory.states[0].pose.position.x == pytest.approx(0.2)
        assert res.trajectory.states[0].pose.orientation.w == pytest.approx(1.0)  # all-zero quaternion = identity
        assert res.topple_probability == pytest.approx(res.trajectory.topple_probability)
        # by object_id, once the feature arrived; horizon 0 = the node's default (60)
        c.features.publish(feature_msg(node.predictor, object_id="mug"))
        assert wait_for(lambda: "mug" in node._features)
        res = call(c.srv, request(object_id="mug"))
        assert res.success and len(res.trajectory.states) == 61 and res.trajectory.object_id == "mug"
        bad = {
            "request header frame_id 'map'": request(frame="map", object_id="mug"),
            "horizon 151 exceeds the model's max_horizon 150": request(object_id="mug", horizon=151),
            "velocity is not finite": request(object_id="mug", v=(0, math.inf, 0)),
            "exceeds max_linear_speed": request(object_id="mug", v=(30.0, 0, 0)),
            "no shape feature received for object 'cup' (known objects: mug)": request(object_id="cup"),
            "cloud: cloud has no z field": request(cloud=no_xyz()),
            "cloud has 0 finite points": request(cloud=xyz_to_cloud(np.full((9, 3), np.nan), "world")),
            "cloud frame_id 'camera' is not the table frame": request(cloud=xyz_to_cloud(CLOUD, "camera")),
            "initial_pose: orientation is not finite": request(object_id="mug", orientation=(0, 0, math.nan, 1)),
            # an initial pose far from its cloud is a mix-up, not a push
            "is 70.00 m from the cloud's centre": request(cloud=xyz_to_cloud(CLOUD, "world"),
                                                          position=(0.2, 70.1, 0.04)),
        }
        for reason, req in bad.items():
            res = call(c.srv, req)
            assert not res.success and reason in res.message, (reason, res.message)
        assert call(c.srv, request(object_id="mug", horizon=5)).success  # still serving


def test_observed_states_in_a_service_request(rclpy_init, predictor):
    node = predictor()
    c = Client(rclpy_init)
    with Spinner(node, c.node):
        req = request(cloud=xyz_to_cloud(CLOUD, "world"), horizon=10)
        req.observed = [state_msg(T0 + k, pos=(0.2 + 0.01 * k, 0.1, 0.04)) for k in (1, 2)]
        res = call(c.srv, req)
        assert res.success and res.trajectory.steps_in == 2
        assert [s.pose.position.x for s in res.trajectory.states[1:3]] == pytest.approx([0.21, 0.22])
        req.observed[1].header.frame_id = "odom"
        res = call(c.srv, req)
        assert not res.success and "observed state frame_id 'odom'" in res.message


@pytest.mark.parametrize("content, reason", [
    (None, "does not exist"),
    (b"not a checkpoint at all", "model.pt"),  # the checkpoint loader's reason names the file
])
def test_unloadable_model_stops_the_node(tmp_path, content, reason):
    path = tmp_path / "model.pt"
    if content is not None:
        path.write_bytes(content)
    run = subprocess.run([sys.executable, "-m", "physdyn_ros.nodes.predictor_node", "--ros-args",
                          "-p", f"model_path:={path}"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 1
    assert "cannot start: cannot load model from" in run.stderr and reason in run.stderr, run.stderr[-2000:]


def plan_request(goal=(0.3, 0.12, 0.0), start=(0.2, 0.1, 0.0), **kw):
    from physdyn_ros.srv import PlanPush

    req = PlanPush.Request()
    req.header.frame_id = kw.pop("frame", "world")
    req.object_id = kw.pop("object_id", "")
    if "cloud" in kw:
        req.cloud = kw.pop("cloud")
    req.start_from_object_state = kw.pop("start_from_object_state", False)
    for msg, (x, y, yaw) in ((req.start_pose, start), (req.goal_pose, goal)):
        msg.position = point((x, y, 0.04))
        msg.orientation.z, msg.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    req.position_tolerance = kw.pop("position_tolerance", 0.05)
    req.yaw_tolerance = kw.pop("yaw_tolerance", math.pi)
    req.time_budget = kw.pop("time_budget", 0.3)
    for k, v in kw.items():
        setattr(req, k, v)
    return req


def test_plan_push_service(rclpy_init, predictor):
    from physdyn_ros.srv import PlanPush

    node = predictor(plan_max_topple_probability=1.0)  # random weights: topple predictions mean nothing
    c = Client(rclpy_init)
    plan = c.node.create_client(PlanPush, "plan_push")
    with Spinner(node, c.node):
        res = call(plan, plan_request(cloud=xyz_to_cloud(CLOUD, "world")), timeout=30)
        assert res.success, res.message
        v = np.array([res.push_twist.linear.x, res.push_twist.linear.y, res.push_twist.linear.z])
        j = np.array([res.impulse.x, res.impulse.y, res.impulse.z])
        assert np.linalg.norm(v) > 0 and j == pytest.approx(res.mass * v)
        assert res.trajectory.model_id == node.model_id and len(res.trajectory.states) > 10
        last = res.trajectory.states[-1].pose.position
        assert (res.predicted_final_pose.position.x, res.predicted_final_pose.position.y) == pytest.approx(
            (last.x, last.y))
        err = math.hypot(last.x - 0.3, last.y - 0.12)
        assert res.predicted_position_error == pytest.approx(err, abs=1e-6)
        assert res.within_tolerance == (err <= 0.05) and 0 < res.planning_time < 3.0
        # the physics check ran (the hull re-simulated) and the robustness check's spread is reported
        assert 0.0 <= res.physics_topple_probability <= res.topple_probability + 1e-6 and res.spread > 0.0
        # the tiny model has no spread calibration: no success estimate, the topple spread still there
        assert math.isnan(res.success_probability) and math.isfinite(res.trajectory.topple_probability_spread)
        node.set_parameters([Parameter("plan_physics_check", value=False)])
        res = call(plan, plan_request(cloud=xyz_to_cloud(CLOUD, "world")), timeout=30)
        assert res.success and res.physics_topple_probability == -1.0, res.message
        node.set_parameters([Parameter("plan_physics_check", value=True)])
        # by object_id, starting from the latest object_state
        c.features.publish(feature_msg(node.predictor, object_id="box"))
        c.states.publish(state_msg(T0))
        assert wait_for(lambda: node._features.get("box") and node._states.get("box"))
        res = call(plan, plan_request(object_id="box", start=(9.0, 9.0, 0.0), start_from_object_state=True),
                   timeout=30)
        assert res.success, res.message  # the start (9, 9) was ignored: the object_state (0.2, 0.1) is used
        assert res.trajectory.states[0].pose.position.x == pytest.approx(0.2, abs=1e-6)
        bad = {
            "request header frame_id 'map'": plan_request(object_id="box", frame="map"),
            "goal (5.000, 0.000) is off the table": plan_request(object_id="box", goal=(5.0, 0.0, 0.0)),
            "no shape feature received for object 'cup'": plan_request(object_id="cup"),
            "time_budget must be finite and >= 0": plan_request(object_id="box", time_budget=-1.0),
            "goal_pose: position is not finite": plan_request(object_id="box", goal=(math.nan, 0.0, 0.0)),
            # an implausible mass and an unbounded max_speed are refused, not planned for
            "mass 1e+09 kg is not plausible for this object": plan_request(object_id="box", mass=1e9),
            "mass 1e+09 kg is not plausible": plan_request(cloud=xyz_to_cloud(CLOUD, "world"), mass=1e9),
            "mass 1e-05 kg is not plausible": plan_request(cloud=xyz_to_cloud(CLOUD, "world"), mass=1e-5),
            "max_speed 1e+06 m/s exceeds the node's max_linear_speed 5 m/s": plan_request(object_id="box",
                                                                                           max_speed=1e6),
            "start_from_object_state: no object_state of 'mug'": plan_request(
                object_id="mug", cloud=xyz_to_cloud(CLOUD, "world"), start_from_object_state=True),
        }
        for reason, req in bad.items():
            res = call(plan, req, timeout=30)
            assert not res.success and reason in res.message, (reason, res.message)
        node.set_parameters([Parameter("plan_table_bounds", value=[-10.0, 10.0, -10.0, 10.0])])
        res = call(plan, plan_request(object_id="box", goal=(4.0, 0.1, 0.0)), timeout=30)
        assert not res.success and "goal unreachable" in res.message
        assert call(plan, plan_request(object_id="box"), timeout=30).success  # still serving


def test_plan_push_estimates_the_mass_with_the_simulators_density(rclpy_init, predictor):
    """Without a mass, plan_push estimates it from the cloud with the simulator's density (within 10 %), and the
    impulse is that mass times the push velocity."""
    from physdyn_ros.shapes import DEFAULT_DENSITY, resolve_shape

    shape = resolve_shape("box", 3, "")
    true_mass = shape.mass_properties(density=DEFAULT_DENSITY).mass
    cloud = (shape.points + (0.2, 0.1, -shape.vertices[:, 2].min())).astype(np.float32)
    node = predictor(plan_max_topple_probability=1.0)
    c = Client(rclpy_init)
    plan = c.node.create_client(PlanPush, "plan_push")
    with Spinner(node, c.node):
        res = call(plan, plan_request(cloud=xyz_to_cloud(cloud, "world")), timeout=30)
    assert res.success, res.message
    assert res.mass == pytest.approx(true_mass, rel=0.1), (res.mass, true_mass)
    v = np.array([res.push_twist.linear.x, res.push_twist.linear.y, res.push_twist.linear.z])
    assert [res.impulse.x, res.impulse.y, res.impulse.z] == pytest.approx(res.mass * v)


def test_diagnostics_report_the_counters(rclpy_init, predictor):
    """/diagnostics from the predictor: model id, counts, the last refusal (WARN after one)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    node = predictor()
    c = Client(rclpy_init)
    got: list[DiagnosticArray] = []
    c.node.create_subscription(DiagnosticArray, "/diagnostics", got.append, 10)
    with Spinner(node, c.node):
        assert wait_for(lambda: got, 5), "no /diagnostics within 5 s"
        first = {kv.key: kv.value for kv in got[-1].status[0].values}
        assert got[-1].status[0].name == "predictor: predictions" and got[-1].status[0].level == DiagnosticStatus.OK
        assert first["model_id"] == node.model_id and first["refusals"] == "0"
        assert not call(c.srv, request(object_id="nobody")).success
        assert call(c.srv, request(cloud=xyz_to_cloud(CLOUD, "world"), horizon=10)).success
        n = len(got)
        assert wait_for(lambda: len(got) > n, 5)
    status = got[-1].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == DiagnosticStatus.WARN and "no shape feature received for object 'nobody'" in status.message
    assert values["refusals"] == "1" and values["predictions"] == "1" and float(values["latency_p50_ms"]) > 0


def test_live_parameters_are_validated(rclpy_init, predictor):
    """A bad value set at run time is refused with its reason (over DDS, as `ros2 param set` does);
    a bad value at start stops the node with the parameter named."""
    from rcl_interfaces.srv import SetParameters

    node = predictor()
    c = Client(rclpy_init)
    setp = c.node.create_client(SetParameters, "/predictor/set_parameters")
    with Spinner(node, c.node):
        res = call(setp, SetParameters.Request(parameters=[
            Parameter("initial_pose_source", value="tracker").to_parameter_msg()]))
        assert not res.results[0].successful
        assert "initial_pose_source must be one of object_state, shape_feature" in res.results[0].reason
        res = call(setp, SetParameters.Request(parameters=[Parameter("horizon", value=0).to_parameter_msg()]))
        assert not res.results[0].successful  # below the declared range
        res = call(setp, SetParameters.Request(parameters=[
            Parameter("initial_pose_source", value="shape_feature").to_parameter_msg()]))
        assert res.results[0].successful
    assert node.get_parameter("initial_pose_source").value == "shape_feature"
    assert node.get_parameter("horizon").value == 60
    with pytest.raises(ValueError, match="initial_pose_source must be one of object_state, shape_feature"):
        predictor(initial_pose_source="tracker")


def test_predictions_carry_their_novelty(rclpy_init, predictor):
    """A prediction says how far its input lies from the training data. The shipped model (with a
    topple head) gives a finite novelty under 1 for an ordinary push of a small box and over 1 for a 4.9 m/s push
    (faster than any it was trained on); a model without the head says NaN (unknown)."""
    from physdyn_ros.resources import DEFAULT_MODEL

    box = (RNG.uniform(-1, 1, (800, 3)) * (0.04, 0.03, 0.06) + (0.2, 0.1, 0.06)).astype(np.float32)
    node = predictor(model_path=str(DEFAULT_MODEL))
    c = Client(rclpy_init)
    with Spinner(node, c.node):
        usual = call(c.srv, request(cloud=xyz_to_cloud(box, "world"), position=(0.2, 0.1, 0.06)))
        wild = call(c.srv, request(cloud=xyz_to_cloud(box, "world"), position=(0.2, 0.1, 0.06), v=(4.9, 0, 0)))
    assert usual.success and wild.success, (usual.message, wild.message)
    assert 0 < usual.trajectory.novelty < 1 < wild.trajectory.novelty
    plain, c = predictor(), Client(rclpy_init)
    with Spinner(plain, c.node):
        res = call(c.srv, request(cloud=xyz_to_cloud(box, "world"), position=(0.2, 0.1, 0.06)))
    assert res.success and math.isnan(res.trajectory.novelty)


def test_topple_fusion_in_the_service(rclpy_init, predictor, tiny_model):
    """topple_fusion: predict_trajectory with a cloud answers the fused topple probability (what the Python
    Predictor with the same weights gives), requests by object_id (a shape feature, no points) the model's; a
    model without a topple head cannot be fused and the node refuses to start, naming the reason."""
    from physdyn_ros.predictor import Predictor
    from physdyn_ros.resources import DEFAULT_MODEL

    # a slow push of a tall box: the model and its physics disagree enough to tell them apart
    tall = (RNG.uniform(-1, 1, (1500, 3)) * (0.02, 0.02, 0.12) + (0.2, 0.1, 0.12)).astype(np.float32)
    push = dict(position=(0.2, 0.1, 0.12), v=(0.2, 0.0, 0.0), w=(0.0, 0.0, 0.0))
    fused_py = Predictor.load(DEFAULT_MODEL, threads=1, topple_fusion=True)
    plain_py = Predictor.load(DEFAULT_MODEL, threads=1)
    args = (tall.astype(np.float64), push["v"], push["w"], 60, push["position"])
    expected, model_only = (p.rollout(*args).topple_probability for p in (fused_py, plain_py))
    fused_py.close()
    assert abs(expected - model_only) > 0.05  # the scenario: the fusion moves the probability
    node = predictor(model_path=str(DEFAULT_MODEL), topple_fusion=True)
    c = Client(rclpy_init)
    with Spinner(node, c.node):
        res = call(c.srv, request(cloud=xyz_to_cloud(tall, "world"), horizon=60, **push))
        assert res.success, res.message
        assert res.topple_probability == pytest.approx(expected, abs=1e-6)
        c.features.publish(feature_msg(node.predictor, object_id="mug"))
        assert wait_for(lambda: "mug" in node._features)
        res = call(c.srv, request(object_id="mug", horizon=60))
        assert res.success, res.message  # a shape feature carries no points: the model's probability
    node.cleanup()  # releases the fusion's and the physics check's pybullet clients
    assert node.predictor is None
    run = subprocess.run([sys.executable, "-m", "physdyn_ros.nodes.predictor_node", "--ros-args",
                          "-p", f"model_path:={tiny_model}", "-p", "topple_fusion:=true"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 1 and "no whole-push topple head" in run.stderr, run.stderr[-2000:]


def test_the_service_carries_the_calibrated_spread(rclpy_init, predictor):
    """rest_spread (default true): predict_trajectory's trajectory carries the Predictor's calibrated spread for
    the same push; rest_spread false leaves the three fields NaN. A model without a spread calibration of its own
    (the tiny one) still carries the topple spread, the radii NaN."""
    from physdyn_ros.predictor import Predictor
    from physdyn_ros.resources import DEFAULT_MODEL

    push = dict(position=(0.2, 0.1, 0.04), v=(0.5, 0.0, 0.0), w=(0.0, 0.0, 0.5))
    expected = Predictor.load(DEFAULT_MODEL, threads=1).rollout(
        CLOUD.astype(np.float64), push["v"], push["w"], 60, push["position"], spread=True).spread
    assert expected is not None and expected.position > 0 and expected.yaw > 0
    for params, want in (({"model_path": str(DEFAULT_MODEL)}, expected),
                         ({"model_path": str(DEFAULT_MODEL), "rest_spread": False}, None), ({}, "tiny")):
        node = predictor(**params)
        c = Client(rclpy_init)
        with Spinner(node, c.node):
            res = call(c.srv, request(cloud=xyz_to_cloud(CLOUD, "world"), horizon=60, **push))
        assert res.success, res.message
        t = res.trajectory
        if want is None:
            assert math.isnan(t.rest_position_spread) and math.isnan(t.topple_probability_spread)
        elif want == "tiny":
            assert math.isnan(t.rest_position_spread) and math.isnan(t.rest_yaw_spread)
            assert math.isfinite(t.topple_probability_spread)
        else:
            assert t.rest_position_spread == pytest.approx(want.position, rel=1e-5)
            assert t.rest_yaw_spread == pytest.approx(want.yaw, rel=1e-5)
            assert t.topple_probability_spread == pytest.approx(want.topple, abs=1e-6)


def test_plan_push_over_an_ensemble(rclpy_init, predictor, tmp_path):
    """plan_ensemble n > 1: plan_push's robustness check runs on the model and n - 1 members of
    plan_ensemble_models (the message says over how many); too few members, or the shipped members with another
    model, stop the configure with the reason."""
    from physdyn_ros.ros.model import ModelLoadError
    from physdyn_ros.srv import PlanPush

    from test_nodes_support import make_tiny_checkpoint

    other = tmp_path / "other.pt"
    make_tiny_checkpoint(other, seed=1, name="tiny-other")
    for params, reason in (({"plan_ensemble": 2}, "shipped members belong to the shipped model"),
                           ({"plan_ensemble": 3, "plan_ensemble_models": [str(other)]}, "needs 2 further members")):
        with pytest.raises(ModelLoadError, match=reason):
            predictor(**params)
    node = predictor(plan_max_topple_probability=1.0, plan_ensemble=2, plan_ensemble_models=["", str(other)])
    c = Client(rclpy_init)
    plan = c.node.create_client(PlanPush, "plan_push")
    with Spinner(node, c.node):
        res = call(plan, plan_request(cloud=xyz_to_cloud(CLOUD, "world")), timeout=30)
        assert res.success and "over 2 models" in res.message, res.message
        # by object_id, a feature without points: the members cannot encode it, the model checks alone and says so
        c.features.publish(feature_msg(node.predictor, object_id="box"))
        assert wait_for(lambda: node._features.get("box"))
        res = call(plan, plan_request(object_id="box"), timeout=30)
        assert res.success and "checked by the model alone" in res.message, res.message
