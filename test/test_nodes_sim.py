"""The sim node over DDS: pushes, the published true trajectory, rejections, reset, spawning, clouds."""
from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger

from physdyn_ros.conventions import DT
from physdyn_ros.msg import ObjectState
from physdyn_ros.nodes.sim_node import STATE_QOS, SimNode
from physdyn_ros.ros.cloud import cloud_to_xyz
from physdyn_ros.ros.convert import quat_to_matrix, time_to_ns
from physdyn_ros.srv import PushObject, SpawnObject
from test_nodes_support import Spinner, call, tiny_model, wait_for  # noqa: F401 - fixture


def sim_node(**params) -> SimNode:
    return SimNode(parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])


class Recorder:
    """A client node recording the sim's outputs."""

    def __init__(self, rclpy):
        self.node = rclpy.create_node("recorder")
        self.states: list[ObjectState] = []
        self.twists: list[TwistStamped] = []
        self.odom: list[Odometry] = []
        self.clouds: list[PointCloud2] = []
        self.node.create_subscription(ObjectState, "object_state", self.states.append, STATE_QOS)
        self.node.create_subscription(TwistStamped, "initial_twist", self.twists.append, 10)
        self.node.create_subscription(Odometry, "odom", self.odom.append, 200)
        self.node.create_subscription(PointCloud2, "cloud", self.clouds.append, 5)
        self.push = self.node.create_client(PushObject, "push")
        self.reset = self.node.create_client(Trigger, "reset")
        self.spawn = self.node.create_client(SpawnObject, "spawn_object")


def push_request(impulse=(0.0, 0.0, 0.0), velocity=None, object_id="") -> PushObject.Request:
    req = PushObject.Request(object_id=object_id)
    req.impulse.x, req.impulse.y, req.impulse.z = impulse
    if velocity is not None:
        req.use_velocity = True
        req.velocity.linear.x, req.velocity.linear.y, req.velocity.linear.z = velocity[:3]
        req.velocity.angular.x, req.velocity.angular.y, req.velocity.angular.z = velocity[3:]
    return req


def test_push_publishes_initial_twist_then_the_true_trajectory(rclpy_init):
    sim = sim_node(real_time_factor=0.0, category="cylinder", publish_cloud_rate=0.0)
    rec = Recorder(rclpy_init)
    mass = sim.sim.mass
    with Spinner(sim, rec.node):
        assert wait_for(lambda: rec.states, 10), "no idle state published"
        start = rec.states[-1].pose.position
        res = call(rec.push, push_request(impulse=(0.6 * mass, 0.0, 0.0)))
        assert res.success, res.message
        assert res.push_id == 1
        assert res.initial_twist.linear.x == pytest.approx(0.6, rel=1e-6)  # dv = J / m through the COM
        assert wait_for(lambda: len(rec.twists) == 1, 5)
        twist = rec.twists[0]
        assert twist.header.frame_id == "world" and twist.twist.linear.x == pytest.approx(0.6, rel=1e-6)
        t0 = time_to_ns(twist.header.stamp)
        # the trajectory unfolds on object_state: frame k stamped t0 + k DT, until the object rests
        assert wait_for(lambda: len([s for s in rec.states if time_to_ns(s.header.stamp) >= t0]) > 5 and
                        not sim._running, 20)
        after = [s for s in rec.states if time_to_ns(s.header.stamp) >= t0]
        k = [(time_to_ns(s.header.stamp) - t0) / (DT * 1e9) for s in after]
        frames = [s for s, kk in zip(after, k) if abs(kk - round(kk)) < 1e-3 and round(kk) <= len(after)]
        assert round(k[1]) == 1 and frames[0].twist.linear.x == pytest.approx(0.6, rel=1e-6)
        # frame 0 is the pose at the push (the dataset convention: velocity set, pose unchanged)
        assert frames[0].pose.position.x == pytest.approx(start.x, abs=1e-6)
        assert all(b.header.stamp.sec * 10**9 + b.header.stamp.nanosec > a.header.stamp.sec * 10**9 +
                   a.header.stamp.nanosec for a, b in zip(rec.states, rec.states[1:])), "stamps must increase"
        final = frames[-1]
        travelled = final.pose.position.x - start.x
        # Coulomb sliding: d = v^2 / (2 mu g) = 0.36 / (2 * 0.5 * 9.81) = 3.7 cm
        assert travelled == pytest.approx(0.6**2 / (2 * 0.5 * 9.81), rel=0.25)
        assert abs(final.twist.linear.x) < 1e-9 and not final.toppled
        # odom's twist is in the object's own axes (REP 105 / nav_msgs convention)
        moving = next(o for o in rec.odom if abs(o.twist.twist.linear.x) + abs(o.twist.twist.linear.y) > 0.1)
        q = moving.pose.pose.orientation
        body = np.array([moving.twist.twist.linear.x, moving.twist.twist.linear.y, moving.twist.twist.linear.z])
        world = quat_to_matrix([q.x, q.y, q.z, q.w]) @ body
        match = next(s for s in rec.states if s.header.stamp == moving.header.stamp)
        np.testing.assert_allclose(world, [match.twist.linear.x, match.twist.linear.y, match.twist.linear.z],
                                   atol=1e-9)
        assert moving.child_frame_id == "object" and moving.header.frame_id == "world"


def test_push_during_push_is_rejected_and_reset_recovers(rclpy_init):
    sim = sim_node(real_time_factor=1.0, category="box", publish_cloud_rate=0.0)
    rec = Recorder(rclpy_init)
    with Spinner(sim, rec.node):
        first = call(rec.push, push_request(velocity=(1.0, 0.0, 0.0, 0.0, 0.0, 0.0)))
        assert first.success, first.message
        second = call(rec.push, push_request(velocity=(0.0, 1.0, 0.0, 0.0, 0.0, 0.0)))
        assert not second.success and "still running" in second.message and "push 1" in second.message
        res = call(rec.reset, Trigger.Request())
        assert res.success, res.message
        assert not sim._running
        pos, q, v, w = sim.sim.state()
        assert np.linalg.norm(pos[:2]) < 1e-3 and np.linalg.norm(v) < 1e-6
        again = call(rec.push, push_request(velocity=(0.2, 0.0, 0.0, 0.0, 0.0, 0.0)))
        assert again.success and again.push_id == 2


@pytest.mark.parametrize("request_, reason", [
    (push_request(impulse=(math.nan, 0.0, 0.0)), "not finite"),
    (push_request(velocity=(100.0, 0.0, 0.0, 0.0, 0.0, 0.0)), "exceeds max_linear_speed"),
    (push_request(impulse=(50.0, 0.0, 0.0)), "above max_linear_speed"),
    (push_request(impulse=(0.0, 0.0, 0.0)), "impulse is zero"),
    (push_request(impulse=(0.1, 0.0, 0.0), object_id="nope"), "unknown object_id 'nope'"),
])
def test_bad_pushes_are_rejected_with_the_reason(rclpy_init, request_, reason):
    sim = sim_node(real_time_factor=0.0, publish_cloud_rate=0.0)
    rec = Recorder(rclpy_init)
    with Spinner(sim, rec.node):
        res = call(rec.push, request_)
        assert not res.success and reason in res.message, res.message
        assert not sim._running and np.linalg.norm(sim.sim.state()[2]) < 1e-9  # nothing moved
        assert call(rec.push, push_request(impulse=(0.05, 0.0, 0.0))).success  # still serving


def test_spawn_object_service(rclpy_init, tmp_path):
    sim = sim_node(real_time_factor=0.0, publish_cloud_rate=0.0)
    rec = Recorder(rclpy_init)
    cube = tmp_path / "cube.obj"
    v = [(x, y, z) for x in (0, 0.1) for y in (0, 0.06) for z in (0, 0.04)]
    faces = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (3, 7, 8, 4), (1, 5, 7, 3), (2, 4, 8, 6)]
    cube.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v)
                    + "".join(f"f {a} {b} {c}\nf {a} {c} {d}\n" for a, b, c, d in faces))
    with Spinner(sim, rec.node):
        bad = call(rec.spawn, SpawnObject.Request(category="teapot"))
        assert not bad.success and "unknown category 'teapot'" in bad.message
        missing = call(rec.spawn, SpawnObject.Request(mesh_path=str(tmp_path / "none.obj")))
        assert not missing.success and "not found" in missing.message
        res = call(rec.spawn, SpawnObject.Request(object_id="crate", mesh_path=str(cube), x=0.2, yaw=0.5))
        assert res.success, res.message
        assert (res.half_extents.x, res.half_extents.y, res.half_extents.z) == pytest.approx((0.05, 0.03, 0.02))
        assert res.mass == pytest.approx(500.0 * 0.1 * 0.06 * 0.04, rel=1e-3)
        assert wait_for(lambda: rec.states and rec.states[-1].object_id == "crate", 5)
        assert rec.states[-1].pose.position.x == pytest.approx(0.2, abs=2e-3)
        pb = call(rec.spawn, SpawnObject.Request(category="pybullet_data", shape_seed=0))
        assert pb.success and "pybullet_data" in pb.message, pb.message
        # issue 14.3: scale 1000 made a box of 494,000 t; the object in place is kept
        kept = sim.sim.shape.name
        huge = SpawnObject.Request(category="box")
        huge.scale.x = huge.scale.y = huge.scale.z = 1000.0
        res = call(rec.spawn, huge)
        assert not res.success and "a tabletop object must measure 0.01-1 m along each axis" in res.message
        flat = SpawnObject.Request(category="box")
        flat.scale.x, flat.scale.y, flat.scale.z = 1.0, 1.0, 1e-4
        assert "must measure" in call(rec.spawn, flat).message
        assert sim.sim.shape.name == kept
        # the push names the current object
        assert not call(rec.push, push_request(impulse=(0.01, 0, 0), object_id="crate")).success


def test_bad_start_parameters_stop_the_node(rclpy_init):
    with pytest.raises(ValueError, match="unknown category 'teapot'"):
        sim_node(category="teapot")


@pytest.mark.parametrize("source", ["surface", "camera"])
def test_cloud_is_the_posed_object_surface(rclpy_init, source):
    sim = sim_node(category="box", cloud_source=source, publish_cloud_rate=20.0, spawn_pose=[0.1, -0.05, 0.4])
    rec = Recorder(rclpy_init)
    with Spinner(sim, rec.node):
        assert wait_for(lambda: rec.clouds, 10), "no cloud"
        msg = rec.clouds[-1]
        pos, q, _, _ = sim.sim.state()
    assert msg.header.frame_id == "world"
    pts = cloud_to_xyz(msg)
    local = (pts - pos) @ quat_to_matrix(q)  # into the object frame
    half = sim.half_extents()
    # every point lies on one face of the box (within the depth-buffer resolution for the camera)
    dist = np.abs(np.abs(local) - half).min(axis=1)
    assert np.all(np.abs(local) <= half + 3e-3)
    assert np.percentile(dist, 95) < (3e-3 if source == "camera" else 1e-5)
    if source == "surface":
        assert len(pts) == 1024 and local[:, 2].min() < -0.9 * half[2]  # the whole surface, bottom included
    else:  # a partial view: points on the faces turned to the camera only
        cam = (np.asarray(sim.get_parameter("camera_eye").value) - pos) @ quat_to_matrix(q)
        seen = 0
        for axis in range(3):
            for sign in (-1.0, 1.0):
                others = [a for a in range(3) if a != axis]
                on_face = (np.abs(local[:, axis] - sign * half[axis]) < 3e-3) & np.all(
                    np.abs(local[:, others]) < half[others] - 4e-3, axis=1)
                if sign * cam[axis] > half[axis]:
                    seen += on_face.sum() > 20
                else:
                    assert on_face.sum() == 0, f"hidden face {axis}{sign:+} has points"
        assert len(pts) > 200 and seen >= 2


def test_sim_and_perception_publish_diagnostics(rclpy_init, tiny_model):
    """Issue 15.2: /diagnostics from the sim and perception nodes too (the predictor's has its own test)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    from physdyn_ros.nodes.perception_node import PerceptionNode

    sim = sim_node(real_time_factor=0.0, publish_cloud_rate=5.0)
    perception = PerceptionNode(parameter_overrides=[Parameter("model_path", value=str(tiny_model))])
    rec = Recorder(rclpy_init)
    got: dict[str, DiagnosticStatus] = {}
    rec.node.create_subscription(DiagnosticArray, "/diagnostics",
                                 lambda m: got.update({s.name: s for s in m.status}), 10)
    with Spinner(sim, perception, rec.node):
        assert not call(rec.spawn, SpawnObject.Request(category="teapot")).success
        assert wait_for(lambda: "sim: simulation" in got and "perception: clouds" in got
                        and {kv.key: kv.value for kv in got["perception: clouds"].values}["clouds_with_features"]
                        != "0", 15), sorted(got)
    sim_status = got["sim: simulation"]
    values = {kv.key: kv.value for kv in sim_status.values}
    assert sim_status.level == DiagnosticStatus.WARN and "unknown category 'teapot'" in sim_status.message
    assert values["refusals"] == "1" and values["object_id"] == sim.object_id
    perc = {kv.key: kv.value for kv in got["perception: clouds"].values}
    assert perc["model_id"] == perception.predictor.model_id and int(perc["features"]) >= 1
