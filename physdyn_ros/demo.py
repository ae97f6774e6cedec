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
"""``physdyn demo``: start the suite, push the objects of a table one by one, compare predicted and true motion.

One command on the shipped model (or --model PATH). The sim runs as fast as possible (real_time_factor 0). Each
table holds up to --objects objects at once (procedural categories and pybullet_data meshes the model never saw),
spawned through the sim's `spawn_object` service under the ids obj1, obj2, ... around the table's centre; the
perception node tracks them all (single_object false: ids track_<n>), and each sim object is matched to its
tracked id by centroid. Then each object is pushed by its id (`push` service), outwards so that it does not hit
the others; its prediction is asked of the predictor's `predict_trajectory` service by the tracked id, from the
true pose at the push instant (what a tracker would give; the sim's states carry the sim's ids, not the tracked
ones) and the push's initial twist; the true trajectory is the sim's object_state of that id. The next table
replaces the objects (same ids) after a reset, until --pushes objects were pushed, one push each.

What is scored is what the model claims: where the object comes to rest and whether it topples. A push that
topples is scored up to the topple (the last upright frame); where a toppled object rolls afterwards is not
predicted and not scored. Each push gets a verdict: GOOD within 2 cm and 10 deg with the topple predicted right
(the planner's tolerance), FAIR within 5 cm and 30 deg with the topple right, POOR otherwise.
Writes DIR/demo.png (drawn by demo_report.py: one row per table, the whole table with every object's true and
predicted path, then one top view per push at one scale for every push panel: outlines and headings at the start,
the predicted and the true pose, a scale bar, the verdicts), DIR/results.json and the nodes' logs in DIR/logs/.
"""
from __future__ import annotations

import argparse
import json
import math
import threading
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .demo_report import PushResult, plot, summary, verdict

HORIZON = 60
#: A predicted topple: the trajectory's topple probability above this.
TOPPLE_THRESHOLD = 0.5
OUTLINE_POINTS = 400
#: m: the objects of a table sit on a circle of this radius around the table's centre (one object: at it).
TABLE_RADIUS = 0.25
#: m: a tracked feature's centroid must be this close to a sim object to be that object.
MATCH_DISTANCE = 0.03
#: s: the sim's max_push_time in the demo.
MAX_PUSH_TIME = 6.0


def score(pred_pos: np.ndarray, pred_q: np.ndarray, true_pos: np.ndarray, true_q: np.ndarray) -> dict:
    """Errors at the scored step (the last, or the last upright one when the truth topples) and the topple step."""
    from .geometry import quat_angle_between
    from .ros.convert import is_toppled

    n = min(len(pred_pos), len(true_pos))
    tipped = [k for k in range(n) if is_toppled(true_q[k])]
    topple_step = tipped[0] if tipped else -1
    k = n - 1 if topple_step < 0 else max(0, topple_step - 1)
    err = np.linalg.norm(pred_pos[: k + 1] - true_pos[: k + 1], axis=1)
    rot = float(np.degrees(quat_angle_between(np.asarray(pred_q[k]), np.asarray(true_q[k]))))
    return {"scored_step": k, "true_topple_step": topple_step, "position_error_cm": float(100 * err[-1]),
            "mean_position_error_cm": float(100 * err.mean()), "rotation_error_deg": rot}


def push_plan(n: int, seed: int) -> list[tuple[str, int]]:
    """(category, shape_seed) per push: procedural categories with a pybullet_data mesh every third push."""
    from .shapes import CATEGORIES, PYBULLET_DATA_CATEGORY

    rng = np.random.default_rng(seed)
    plan, proc, mesh = [], 0, 0
    for i in range(n):
        if i % 3 == 1:
            plan.append((PYBULLET_DATA_CATEGORY, int(seed) + mesh))
            mesh += 1
        else:
            plan.append((CATEGORIES[proc % len(CATEGORIES)], int(rng.integers(0, 1000))))
            proc += 1
    return plan


class DemoClient:
    """The demo's own node: service clients and recorders, spun on a background thread."""

    def __init__(self) -> None:
        import rclpy
        from geometry_msgs.msg import TwistStamped
        from rclpy.executors import MultiThreadedExecutor

        from .msg import ObjectState, PredictedTrajectory, ShapeFeature
        from rclpy.parameter_client import AsyncParameterClient
        from sensor_msgs.msg import PointCloud2
        from std_srvs.srv import Trigger

        from .ros.qos import CLOUD_QOS, FEATURE_QOS, LATCHED, STATE_QOS, reliable_client
        from .srv import PredictTrajectory, PushObject, SpawnObject

        self.node = rclpy.create_node("physdyn_demo")
        self.lock = threading.Lock()
        self.features: list = []
        self.states: list = []
        self.trajs: list = []
        self.twists: list = []
        self.clouds: list = []
        self.node.create_subscription(ShapeFeature, "shape_feature", self._add(self.features), FEATURE_QOS)
        self.node.create_subscription(ObjectState, "object_state", self._add(self.states), STATE_QOS)
        self.node.create_subscription(PredictedTrajectory, "predicted_trajectory", self._add(self.trajs), LATCHED)
        self.node.create_subscription(TwistStamped, "initial_twist", self._add(self.twists), 10)
        self.node.create_subscription(PointCloud2, "cloud", self._add(self.clouds), CLOUD_QOS)
        self.spawn = reliable_client(self.node, SpawnObject, "spawn_object")
        self.push = reliable_client(self.node, PushObject, "push")
        self.reset = reliable_client(self.node, Trigger, "reset")
        self.predict = reliable_client(self.node, PredictTrajectory, "predict_trajectory")
        self.predictor_params = AsyncParameterClient(self.node, "predictor")
        self.executor = MultiThreadedExecutor(num_threads=2)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _add(self, store: list):
        def cb(msg) -> None:
            with self.lock:
                store.append(msg)
        return cb

    def _spin(self) -> None:
        from .ros.run import spin_once

        while not self._stop.is_set():
            spin_once(self.executor, 0.05)

    def call(self, client, request, timeout: float = 60.0):
        if not client.wait_for_service(timeout_sec=timeout):
            raise RuntimeError(f"service {client.srv_name} is not available")
        return self.result(client.call_async(request), client.srv_name, timeout)

    def result(self, future, what: str, timeout: float = 60.0):
        deadline = time.monotonic() + timeout
        while not future.done():
            if time.monotonic() > deadline:
                raise RuntimeError(f"no answer from {what} within {timeout:.0f} s")
            time.sleep(0.005)
        return future.result()

    def wait(self, predicate, timeout: float, what: str):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                value = predicate()
            if value:
                return value
            time.sleep(0.01)
        raise RuntimeError(f"timed out after {timeout:.0f} s waiting for {what}")

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5.0)
        # Jazzy's Executor.shutdown does not wait for running callbacks: wait for them before destroying.
        self.executor._work_tracker.wait(5.0)
        deadline = time.monotonic() + 5.0
        while not all(f.done() for f in list(self.executor._futures)) and time.monotonic() < deadline:
            time.sleep(0.01)
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()


def table_slots(n: int, rng: np.random.Generator) -> list[tuple[float, float]]:
    """(x, y) of n objects: on a circle of TABLE_RADIUS around the table's centre, one object at the centre."""
    if n == 1:
        return [(0.0, 0.0)]
    phase = float(rng.uniform(0.0, 2.0 * math.pi))
    return [(TABLE_RADIUS * math.cos(phase + 2 * math.pi * k / n), TABLE_RADIUS * math.sin(phase + 2 * math.pi * k / n))
            for k in range(n)]


def latest_state(c: DemoClient, object_id: str, after_ns: int = -1):
    """The newest object_state of `object_id` stamped after after_ns (None if none)."""
    from .ros.convert import time_to_ns

    return next((s for s in reversed(c.states) if s.object_id == object_id and time_to_ns(s.header.stamp) > after_ns),
                None)


def match_tracks(c: DemoClient, positions: dict[str, np.ndarray], after_ns: int) -> dict[str, str] | None:
    """{sim id: tracked id} from the newest cloud stamped after after_ns whose features include one within
    MATCH_DISTANCE of every position (None while there is none: perception has not seen them yet)."""
    from .ros.convert import time_to_ns

    stamps = sorted({time_to_ns(f.header.stamp) for f in c.features if time_to_ns(f.header.stamp) > after_ns})
    for t in reversed(stamps):
        feats = [f for f in c.features if time_to_ns(f.header.stamp) == t]
        out = {}
        for oid, p in positions.items():
            dist = {f.object_id: math.hypot(f.centroid.x - p[0], f.centroid.y - p[1]) for f in feats}
            best = min(dist, key=dist.get) if dist else ""
            if not best or dist[best] > MATCH_DISTANCE or best in out.values():
                break
            out[oid] = best
        else:
            return out
    return None


def set_predictor_object(c: DemoClient, tracked_id: str, attempts: int = 3) -> None:
    """Point the predictor's object_id parameter at the pushed object. Fast DDS can drop a service reply sent
    before the client's reply reader is matched, and the request then waits forever: wait for the parameter services,
    then retry the (idempotent) request a few times with a shorter timeout."""
    from rclpy.parameter import Parameter

    if not c.predictor_params.wait_for_services(timeout_sec=30.0):
        raise RuntimeError("the predictor's parameter services are not available")
    for attempt in range(attempts):
        try:
            res = c.result(c.predictor_params.set_parameters([Parameter("object_id", value=tracked_id)]),
                           "predictor parameters", timeout=10.0)
        except RuntimeError:
            if attempt == attempts - 1:
                raise
            continue
        if not res.results or not res.results[0].successful:
            raise RuntimeError(f"the predictor refused object_id {tracked_id!r}: "
                               f"{res.results[0].reason if res.results else 'no result'}")
        return


def set_table(c: DemoClient, table: int, plan: list[tuple[str, int]], previous: list[str],
              rng: np.random.Generator) -> tuple[dict[str, object], dict[str, str], int]:
    """Spawn the table's objects (replacing the previous table's after a reset), wait until perception tracks
    them. Returns ({sim id: SpawnObject response}, {sim id: tracked id}, stamp of the spawn)."""
    from .ros.convert import time_to_ns
    from .srv import SpawnObject

    ids = [f"obj{k + 1}" for k in range(len(plan))]
    # clear the previous table first: its objects lie where they were pushed (or back at slots of another
    # phase after a reset), where a new object's slot may overlap one of them
    for oid in previous:
        done = c.call(c.spawn, SpawnObject.Request(object_id=oid, category="remove"))
        if not done.success:
            raise RuntimeError(f"table {table}: removing {oid}: {done.message}")
    spawned = {}
    for oid, (category, shape_seed), (x, y) in zip(ids, plan, table_slots(len(plan), rng)):
        yaw = float(rng.uniform(-math.pi, math.pi))
        res = c.call(c.spawn, SpawnObject.Request(object_id=oid, category=category, shape_seed=shape_seed, x=x,
                                                  y=y, yaw=yaw))
        if not res.success:
            raise RuntimeError(f"table {table}, {oid}: {res.message}")
        spawned[oid] = res
    n_states = len(c.states)
    last = c.wait(lambda: next((s for s in c.states[n_states:] if s.object_id == ids[-1]), None), 10,
                  "the new objects' states")
    t_spawn = time_to_ns(last.header.stamp)

    def tracks():
        pos = {}
        for oid in ids:
            s = latest_state(c, oid)
            pos[oid] = np.array([s.pose.position.x, s.pose.position.y])
        return match_tracks(c, pos, t_spawn)

    tracked = c.wait(tracks, 30, f"perception to track the {len(ids)} objects of table {table} (is the perception "
                     "node running? see logs/perception.log)")
    return spawned, tracked, t_spawn


def run_push(c: DemoClient, index: int, table: int, object_id: str, tracked_id: str, spawned, category: str,
             rng: np.random.Generator, horizon: int) -> PushResult:
    from .ros.convert import time_to_ns
    from .srv import PredictTrajectory, PushObject

    shape = spawned.message.split(": ", 1)[-1].split(" (")[0]
    first = latest_state(c, object_id)
    t_first = time_to_ns(first.header.stamp)
    cloud = c.wait(lambda: next((m for m in reversed(c.clouds) if time_to_ns(m.header.stamp) >= t_first), None),
                   30, f"a cloud of {object_id}")
    he = np.array([spawned.half_extents.x, spawned.half_extents.y, spawned.half_extents.z])
    outline = body_points(cloud, first.pose, rng, he)
    # The predictor's own prediction for each initial_twist follows its object_id parameter: the pushed object.
    set_predictor_object(c, tracked_id)
    # A push through a point beside the centre of mass, outwards from the table's centre (away from the other
    # objects): it slides and spins; sometimes it topples.
    com = first.pose.position
    speed = float(rng.uniform(0.3, 1.2))
    az = math.atan2(com.y, com.x) + float(rng.uniform(-0.5, 0.5)) if math.hypot(com.x, com.y) > 0.05 else \
        float(rng.uniform(-math.pi, math.pi))
    d = np.array([math.cos(az), math.sin(az), 0.0])
    side = np.array([-d[1], d[0], 0.0])
    point = np.array([com.x, com.y, com.z]) + side * rng.uniform(-0.5, 0.5) * he[:2].min() \
        + np.array([0, 0, rng.uniform(0.0, 0.6) * he[2]])
    impulse = spawned.mass * speed * d
    req = PushObject.Request(object_id=object_id)
    req.impulse.x, req.impulse.y, req.impulse.z = (float(v) for v in impulse)
    req.point.x, req.point.y, req.point.z = (float(v) for v in point)
    n_twists = len(c.twists)
    res = c.call(c.push, req)
    if not res.success:
        raise RuntimeError(res.message)
    twist = c.wait(lambda: c.twists[n_twists:] and c.twists[n_twists], 10, "initial_twist")
    t0 = time_to_ns(twist.header.stamp)
    frame0 = c.wait(lambda: next((s for s in c.states if s.object_id == object_id
                                  and time_to_ns(s.header.stamp) == t0), None), 10, "the state at the push")
    ask = PredictTrajectory.Request(object_id=tracked_id, horizon=horizon)
    ask.header.frame_id, ask.header.stamp = frame0.header.frame_id, frame0.header.stamp
    ask.initial_pose, ask.initial_twist = frame0.pose, res.initial_twist
    answer = c.call(c.predict, ask)
    if not answer.success:
        raise RuntimeError(f"predict_trajectory for {tracked_id} ({object_id}): {answer.message}")
    traj = answer.trajectory
    dt_ns = time_to_ns(traj.states[1].header.stamp) - t0 if len(traj.states) > 1 else int(1e9 / 15)
    end_ns = t0 + horizon * dt_ns

    def truth():
        after = [s for s in c.states if s.object_id == object_id and time_to_ns(s.header.stamp) > t0]
        # the sim holds settled objects exactly still (zero twist): the trajectory is complete then
        done = any(time_to_ns(s.header.stamp) >= end_ns or (s.twist.linear.x == s.twist.linear.y ==
                   s.twist.linear.z == s.twist.angular.x == s.twist.angular.y == s.twist.angular.z == 0.0)
                   for s in after)
        return done and [s for s in c.states if s.object_id == object_id and t0 <= time_to_ns(s.header.stamp) <= end_ns]

    true_states = c.wait(truth, 60, "the true trajectory on object_state")
    by_step = {round((time_to_ns(s.header.stamp) - t0) / dt_ns): s for s in true_states}
    true_pos, true_q, last = [], [], by_step[0]
    for k in range(horizon + 1):  # frames after rest repeat the rest pose (the dataset convention)
        last = by_step.get(k, last)
        true_pos.append([last.pose.position.x, last.pose.position.y, last.pose.position.z])
        o = last.pose.orientation
        true_q.append([o.x, o.y, o.z, o.w])
    # the push ends when every object rests (or after max_push_time): then the next one may start
    rest = c.wait(lambda: next((s for s in c.states if s.object_id == object_id and time_to_ns(s.header.stamp) > t0
                                and (time_to_ns(s.header.stamp) >= t0 + (MAX_PUSH_TIME - 0.5 / 15) * 1e9
                                     or s.twist.linear.x == s.twist.linear.y == s.twist.linear.z == 0.0)), None),
                  60, f"the push of {object_id} to end")
    # where perception sees it at rest: the same tracked id?
    after = match_tracks_one(c, object_id, np.array([rest.pose.position.x, rest.pose.position.y]),
                             time_to_ns(rest.header.stamp))
    pred_pos = np.array([[s.pose.position.x, s.pose.position.y, s.pose.position.z] for s in traj.states])
    pred_q = np.array([[s.pose.orientation.x, s.pose.orientation.y, s.pose.orientation.z, s.pose.orientation.w]
                       for s in traj.states])
    true_pos, true_q = np.array(true_pos), np.array(true_q)
    n = min(len(pred_pos), len(true_pos))
    sc = score(pred_pos, pred_q, true_pos, true_q)
    k = sc["scored_step"]
    predicted_topple = bool(traj.topple_probability > TOPPLE_THRESHOLD)
    toppled = sc["true_topple_step"] >= 0
    return PushResult(
        index=index, shape=shape, category=category, table=table, object_id=object_id, tracked_id=tracked_id,
        tracked_id_after=after, impulse=impulse.round(4).tolist(),
        initial_lin_vel=[res.initial_twist.linear.x, res.initial_twist.linear.y, res.initial_twist.linear.z],
        initial_ang_vel=[res.initial_twist.angular.x, res.initial_twist.angular.y, res.initial_twist.angular.z],
        predicted_final=pred_pos[k].tolist(), true_final=true_pos[k].tolist(), **sc,
        topple_probability=float(traj.topple_probability), predicted_topple=predicted_topple, toppled=toppled,
        verdict=verdict(sc["position_error_cm"], sc["rotation_error_deg"], predicted_topple == toppled),
        predicted_xy=pred_pos[:n, :2].round(5).tolist(), true_xy=true_pos[:n, :2].round(5).tolist(),
        predicted_quat=pred_q[k].tolist(), true_quat=true_q[k].tolist(), start_quat=true_q[0].tolist(),
        outline=outline.round(5).tolist())


def match_tracks_one(c: DemoClient, object_id: str, xy: np.ndarray, after_ns: int, timeout: float = 10.0) -> str:
    """The tracked id nearest `xy` (within MATCH_DISTANCE) in a cloud stamped after after_ns; "" if none."""
    try:
        return c.wait(lambda: (match_tracks(c, {object_id: xy}, after_ns) or {}).get(object_id), timeout,
                      f"the tracked id of {object_id} at rest")
    except RuntimeError:
        return ""


def body_points(cloud, pose, rng: np.random.Generator, half_extents: np.ndarray) -> np.ndarray:
    """The object's surface points in its body frame at `pose`, at most OUTLINE_POINTS: the points of the table
    frame cloud (every object) within its half extents (+ 5 mm)."""
    from scipy.spatial.transform import Rotation

    from .ros.cloud import cloud_to_xyz

    pts = cloud_to_xyz(cloud).astype(np.float64)
    c = np.array([pose.position.x, pose.position.y, pose.position.z])
    q = [pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w]
    local = Rotation.from_quat(q).inv().apply(pts - c)
    local = local[np.all(np.abs(local) <= np.asarray(half_extents) + 0.005, axis=1)]
    if len(local) > OUTLINE_POINTS:
        local = local[rng.choice(len(local), OUTLINE_POINTS, replace=False)]
    return local


def check_no_suite_running(timeout: float = 1.5) -> None:
    """Refuse to start a second suite on the same ROS domain: two sims would answer the same services."""
    import os

    import rclpy

    probe = rclpy.create_node("physdyn_demo_probe")
    try:
        time.sleep(timeout)  # discovery
        names = set(probe.get_node_names())
    finally:
        probe.destroy_node()
    clash = sorted(names & {"sim", "perception", "predictor"})
    if clash:
        raise RuntimeError(f"nodes {clash} already run on ROS_DOMAIN_ID {os.environ.get('ROS_DOMAIN_ID', '0')}; "
                           "stop them or run the demo with another ROS_DOMAIN_ID")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--pushes", type=int, default=6, help="number of pushes (objects, each pushed once), "
                        "default 6")
    parser.add_argument("--objects", type=int, default=3, help="objects on the table at once (1-6), default 3")
    parser.add_argument("--output", type=Path, default=Path("runs/demo"), help="folder for demo.png, "
                        "results.json and logs/ (default runs/demo)")
    parser.add_argument("--model", default=None, help="checkpoint (default: the shipped model)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the objects, yaws and pushes")
    parser.add_argument("--horizon", type=int, default=HORIZON, help="predicted steps of 1/15 s (default 60)")
    parser.add_argument("--startup-timeout", type=float, default=240.0, help="s to wait for the nodes")


def run(args: argparse.Namespace) -> int:
    import rclpy

    from .launcher import Suite
    from .resources import DEFAULT_MODEL

    if args.pushes < 1:
        raise ValueError("--pushes must be >= 1")
    if not 1 <= args.objects <= 6:
        raise ValueError("--objects must be in 1..6")
    if not 1 <= args.horizon <= 150:
        raise ValueError("--horizon must be in 1..150")
    model = Path(args.model).expanduser().resolve() if args.model else DEFAULT_MODEL
    if not model.is_file():
        raise FileNotFoundError(f"model {model} does not exist" + ("" if args.model else
                                "; the shipped model is missing: pass --model PATH to a checkpoint"))
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    overrides = {
        "sim": ["real_time_factor:=0.0", "publish_cloud_rate:=5.0", f"max_push_time:={MAX_PUSH_TIME}", "rate:=15.0",
                "object_id:=obj1"],  # the start object is the first table's obj1 (replaced by its spawn)
        # at real_time_factor 0 a whole push happens between two clouds: the gate must cover the slide (the
        # objects stand 0.43 m apart) and the timeout the push's simulated time (the next cloud's stamp is later)
        "perception": [f"model_path:={model}", "single_object:=false", "id_prefix:=track_", "track_gate:=0.3",
                       f"track_timeout:={MAX_PUSH_TIME + 4.0}"],
        # the scored prediction comes from predict_trajectory (true pose at the push); the predictor's own one
        # for each initial_twist (its object_id parameter, set per push) starts from the feature
        "predictor": [f"model_path:={model}", f"horizon:={args.horizon}", "max_feature_age:=30.0",
                      "initial_pose_source:=shape_feature"],
    }
    rclpy.init()
    suite = None
    client = None
    try:
        check_no_suite_running()
        t_start = time.monotonic()
        print(f"physdyn demo: starting sim, perception, predictor (model {model}); logs in {out / 'logs'}",
              flush=True)
        suite = Suite(overrides=overrides, log_dir=out / "logs").start()
        suite.wait_ready(args.startup_timeout)
        print(f"physdyn demo: nodes ready in {time.monotonic() - t_start:.1f} s", flush=True)
        client = DemoClient()
        rng = np.random.default_rng(args.seed)
        results: list[PushResult] = []
        header = (f"{'#':>2} {'object':<34} {'predicted (x, y) m':>19} {'true (x, y) m':>17} {'at s':>5} "
                  f"{'err cm':>7} {'err deg':>8} {'topple p':>8} {'toppled':>7} verdict")
        plan = push_plan(args.pushes, args.seed)
        ids: list[str] = []
        for table, first in enumerate(range(0, len(plan), args.objects), start=1):
            objects = plan[first:first + args.objects]
            spawned, tracked, _ = set_table(client, table, objects, ids, rng)
            ids = list(spawned)
            print(f"table {table}: " + ", ".join(f"{oid} = {spawned[oid].message.split(': ', 1)[-1].split(' (')[0]}"
                                                 f" (tracked as {tracked[oid]})" for oid in ids), flush=True)
            print(header)
            for oid, (category, _) in zip(ids, objects):
                i = len(results) + 1
                r = run_push(client, i, table, oid, tracked[oid], spawned[oid], category, rng, args.horizon)
                results.append(r)
                name = f"{oid} {r.shape}"
                print(f"{i:>2} {name:<34} ({r.predicted_final[0]:+.3f}, {r.predicted_final[1]:+.3f})  "
                      f"({r.true_final[0]:+.3f}, {r.true_final[1]:+.3f}) {r.scored_step / 15:>5.1f} "
                      f"{r.position_error_cm:>7.1f} {r.rotation_error_deg:>8.1f} {r.topple_probability:>8.2f} "
                      f"{'yes' if r.toppled else 'no':>7} {r.verdict}"
                      + ("" if r.tracked_id_after == r.tracked_id else
                         f"  (tracked id {r.tracked_id} -> {r.tracked_id_after or 'lost'})"), flush=True)
                dead = suite.dead()
                if dead is not None:
                    raise RuntimeError(f"node '{dead.name}' died (see {out / 'logs' / (dead.name + '.log')})")
        pos = np.array([r.position_error_cm for r in results])
        rot = np.array([r.rotation_error_deg for r in results])
        model_id = client.trajs[-1].model_id if client.trajs else "?"
        stable = sum(r.tracked_id_after == r.tracked_id for r in results)
        print(f"tracking: {stable} of {len(results)} pushed objects kept their tracked id")
        print(f"errors over {len(results)} pushes (a toppled push up to its topple): median {np.median(pos):.1f} cm,"
              f" {np.median(rot):.1f} deg; mean {pos.mean():.1f} cm, {rot.mean():.1f} deg")
        print(f"verdict: {summary(results)}")
        plot(results, out / "demo.png", model_id)
        (out / "results.json").write_text(json.dumps({"model": str(model), "model_id": model_id,
                                                      "horizon": args.horizon, "seed": args.seed,
                                                      "pushes": [asdict(r) for r in results]}, indent=1))
        print(f"wrote {out / 'demo.png'} and {out / 'results.json'} ({time.monotonic() - t_start:.1f} s)")
        return 0
    finally:
        if client is not None:
            client.close()
        if suite is not None:
            suite.stop()
        rclpy.try_shutdown()
