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
"""The perception node's tracking against the simulator's truth: three objects, depth-camera clouds at 15 Hz.

    .venv/bin/python bench/bench_tracking.py [--pushes 24] [--rest-seconds 60] [--resolution 320 240] [--seed 0]
        [--goals 16] [--objects box:9001,speaker:9002,wedge:9003]

A pybullet world with three objects (by default a box, a speaker and a wedge of shapes no model was trained on;
--objects picks others, category:seed each) is rendered by
the sim's depth camera (sim/camera.py, the sim node's default eye and target) every 1/15 s of simulated time; each
cloud goes through the perception node's own processing (PerceptionNode.process: segmentation, features, tracking),
as the node does on `cloud`, with the perception settings of config/state_source_perception.yaml (what
`physdyn up --state-source perception` runs). After --rest-seconds at rest, --pushes pushes by id, one every 3 s,
each a random initial velocity (0.3-1.2 m/s along the table, spin up to 3 rad/s; set at a random instant between
two clouds) of a random object, drawn so that
its slide keeps clear of the other objects and ends in view (collisions would be pushes the bench did not make).
Track ids are matched to the sim's ids on the first cloud (nearest position). Figures:
  * tracked position error (tracked COM estimate vs the true COM), at rest and moving (true speed > 2 cm/s),
    median and p90; orientation error of the rotation since the first cloud (tracked vs true), median;
  * onsets: the share of pushes with an initial_state of the pushed object's track stamped from 1 frame before to
    5 frames after the push's true instant, the delay (frames from that instant to the onset's stamp, median),
    false onsets (an initial_state with no push while the
    sim's object stood still), at rest and in all, and onsets of objects the sim moved without a push
    (onsets_unpushed_motion: a collision, or a slide's end seen as a second push); initial speed error
    (relative) and spin error (rad/s) against the velocity the push set, median;
  * the prediction error ratio: the shipped model's final position error (against where the object came to
    rest) from perception's initial_state and the --steps-in tracked states after it (the predictor's steps_in
    in the perception overlay unless given: what the suite publishes last), over the same model fed the true
    initial pose and twist, on the same pushes and the same cloud (medians);
  * per object: its position error at rest and moving, its orientation error moving (medians) and its pushes'
    prediction error over the true state's (median of the per-push ratios, the true state's error taken as at
    least 1 mm): which shape's view costs what;
  * ids kept: pushes after which every track still sits on the object it was matched to (no swap, none lost),
    judged on the last of the push window's final 5 clouds that shows all three objects (a sparse object can
    miss one cloud's sample without losing its id);
  * perception's cost per 100k-point cloud with three objects (p50 CPU time of one thread; the node's test
    scene), and the sim's rendering and processing time per camera cloud (p50 wall).
  * with --depth-noise / --flying-pixels every camera cloud first gets a depth camera's errors (sensor_noise),
    which the sim's renderer lacks;
  * push_to_goal (--goals trials, 0 for none): the four nodes in this process on the sim's 15 Hz camera clouds, one
    object of a family or seed no model was trained on, a goal 10-18 cm away (tolerance 3 cm, any yaw, up to 3
    pushes), run once with the suite's state_source perception overlay and once with the same overlay but the
    sim's ground truth as the predictor's and the pusher's state (state_source sim, no tracked steps), on the same
    shape, spawn and goal: both plan from the same one-view camera clouds; a trial succeeds when the sim's truth
    has the object upright within the tolerance (not when the pusher believes so).
The last line is one JSON object with the issue's keys.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DT_NS = 66_666_667  # 15 Hz
OBJECTS = (("a", "box", 9001, (0.05, -0.2)), ("b", "speaker", 9002, (0.05, 0.2)), ("c", "wedge", 9003, (-0.2, 0.0)))
VIEW = np.array([0.25, 0.3])  # m: |x|, |y| of the table area the camera sees whole
MOVING = 0.02  # m/s: faster than this (true COM speed) counts as moving
FRAMES_PER_PUSH = 45


def parse_objects(text: str) -> tuple:
    """--objects "category:seed,category:seed,category:seed" -> OBJECTS' form, at OBJECTS' places and ids."""
    from physdyn_ros.shapes import ALL_CATEGORIES

    specs = [s.strip() for s in text.split(",") if s.strip()]
    if len(specs) != len(OBJECTS):
        raise ValueError(f"--objects needs {len(OBJECTS)} category:seed entries, got {len(specs)}")
    out = []
    for (oid, _, _, xy), spec in zip(OBJECTS, specs):
        category, _, seed = spec.partition(":")
        if category not in ALL_CATEGORIES or not seed.strip().isdigit():
            raise ValueError(f"--objects entry '{spec}' is not category:seed (a category of {ALL_CATEGORIES}, a "
                             "seed >= 0)")
        out.append((oid, category, int(seed), xy))
    return tuple(out)


def relative_error(q_track: np.ndarray, q_track0: np.ndarray, q_true: np.ndarray, q_true0: np.ndarray) -> float:
    """rad between the tracked rotation since its first cloud and the true one since the same instant."""
    from scipy.spatial.transform import Rotation as R

    tracked = R.from_quat(q_track) * R.from_quat(q_track0).inv()
    true = R.from_quat(q_true) * R.from_quat(q_true0).inv()
    return float((tracked * true.inv()).magnitude())


def quat(msg) -> np.ndarray:
    o = msg.pose.orientation
    return np.array([o.x, o.y, o.z, o.w])


def xyz(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z])


def frame_of(state) -> int:
    """The bench frame of an ObjectState's stamp (frame k is stamped 1 s + k / 15 s)."""
    from physdyn_ros.ros.convert import time_to_ns

    return round((time_to_ns(state.header.stamp) - 10**9) / DT_NS)


def late(state, push: dict) -> float:
    """Frames from a push's true instant to an ObjectState's stamp (its onset estimate)."""
    from physdyn_ros.ros.convert import time_to_ns

    return (time_to_ns(state.header.stamp) - push["t_ns"]) / DT_NS


def free_push(sim, rng: np.random.Generator, radii: dict[str, float]) -> tuple[str, np.ndarray]:
    """A random object and a velocity (0.3-1.2 m/s) whose Coulomb slide (v^2 / (2 mu g), 30 % longer for the
    spin) keeps the two objects' bounding radii (radii: sim id -> m, about the centre of mass, any yaw) plus 3 cm
    apart from every other object and ends in the camera's view: a push that hits nothing."""
    states = {oid: s[0] for oid, s in sim.states().items()}
    for _ in range(1000):
        oid = str(rng.choice(list(states)))
        speed = float(rng.uniform(0.3, 1.2))
        heading = float(rng.uniform(-math.pi, math.pi))
        d = np.array([math.cos(heading), math.sin(heading)])
        path = states[oid][:2] + np.linspace(0.0, 1.3 * speed ** 2 / (2 * 0.5 * 9.81), 20)[:, None] * d
        clear = all(np.min(np.linalg.norm(path - q[:2], axis=1)) > radii[oid] + radii[o] + 0.03
                    for o, q in states.items() if o != oid)
        if clear and np.all(np.abs(path[-1]) < VIEW):
            return oid, np.array([speed * d[0], speed * d[1], 0.0])
    raise RuntimeError("no push keeps clear of the other objects: the objects crowd the table")


def sensor_noise(points: np.ndarray, eye, rng: np.random.Generator, depth_noise: float,
                 flying: float) -> np.ndarray:
    """A depth camera's errors on exact rendered points: Gaussian noise along each ray, depth_noise (m) at 1 m
    range growing with the range squared, and a share `flying` of the points moved 1-6 cm farther along their ray
    (mixed pixels; the renderer has neither)."""
    ray = points - np.asarray(eye, dtype=np.float64)
    rng_m = np.linalg.norm(ray, axis=1, keepdims=True)
    unit = ray / np.maximum(rng_m, 1e-9)
    out = points + unit * (depth_noise * rng_m ** 2 * rng.standard_normal((len(points), 1)))
    moved = rng.random(len(points)) < flying
    out[moved] += unit[moved] * rng.uniform(0.01, 0.06, (int(moved.sum()), 1))
    return out


def perception_100k_ms() -> float:
    """p50 CPU ms of PerceptionNode.process on the tests' 100k-point scene of three objects, one thread."""
    from rclpy.parameter import Parameter

    from physdyn_ros.nodes.perception_node import PerceptionNode
    from physdyn_ros.perception.synthetic import tabletop_scene
    from physdyn_ros.ros.cloud import xyz_to_cloud
    from physdyn_ros.ros.convert import ns_to_time

    scene = tabletop_scene(100_000)
    cam = scene.camera
    node = PerceptionNode(parameter_overrides=[
        Parameter("single_object", value=False), Parameter("num_threads", value=1),
        Parameter("sensor_frame", value="cam"), Parameter("sensor_transform", value=cam.as_list())])
    msg = xyz_to_cloud(scene.points, "cam", ns_to_time(10**9))
    node.process(msg)
    cpu = []
    for k in range(30):
        msg.header.stamp = ns_to_time(10**9 + (k + 1) * DT_NS)
        t = time.process_time()
        node.process(msg)
        cpu.append(time.process_time() - t)
    node.destroy_node()
    return 1e3 * float(np.median(cpu))


#: push_to_goal trials: families and first seeds (no training set used them); each trial takes the first seed
#: from there whose shape a push can slide (squat_seed)
GOAL_SHAPES = (("box", 9101), ("speaker", 9102), ("wedge", 9103), ("cylinder", 9104), ("prism", 9105),
               ("capsule", 9106), ("superellipsoid", 9107), ("polyhedron", 9108))
GOAL_TOLERANCE = 0.03  # m; the yaw is free (a tracked orientation is relative to the first cloud)


def goal_trial(source: str, category: str, seed: int, spawn: tuple, goal: tuple, timeout: float = 120.0) -> dict:
    """One push_to_goal on the four nodes in this process, the suite's state_source perception overlay applied
    (both sources on the same 15 Hz camera clouds, planned as one camera's view: only where the pusher and the
    predictor read states differs, and the sim's run has no tracked states to refine its predictions with);
    judged by the sim's truth: the object rests upright within GOAL_TOLERANCE of the goal."""
    import threading

    from rclpy.action import ActionClient
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.parameter import Parameter
    from scipy.spatial.transform import Rotation

    from physdyn_ros.action import PushToGoal
    from physdyn_ros.nodes.perception_node import PerceptionNode
    from physdyn_ros.nodes.predictor_node import PredictorNode
    from physdyn_ros.nodes.pusher_node import PusherNode
    from physdyn_ros.nodes.sim_node import SimNode
    from physdyn_ros.ros.convert import pose, yaw_quaternion
    from physdyn_ros.suite import parse_overrides, state_source_overlay

    # both runs take the perception overlay (camera clouds, a one-view cloud's planning); the sim's run reads its
    # states from the sim's ground truth instead, with no tracked states to refine predictions with
    overlay = {node: parse_overrides(node, values) for node, values in state_source_overlay("perception").items()}
    if source == "sim":
        for node in ("predictor", "pusher"):
            overlay[node] = {k: v for k, v in overlay[node].items() if k != "steps_in"} | {"state_source": "sim"}

    def params(node: str, extra: dict) -> list:
        values = {**overlay.get(node, {}), **extra}
        return [Parameter(k, value=v) for k, v in values.items()]

    tracked_id = "seen" if source == "perception" else "object"  # perception's id is never the sim's there
    sim = SimNode(parameter_overrides=params("sim", {"category": category, "shape_seed": seed,
                                                     "spawn_pose": [float(v) for v in spawn]}))
    nodes = [sim, PerceptionNode(parameter_overrides=params("perception", {"object_id": tracked_id})),
             PredictorNode(parameter_overrides=params("predictor", {})),
             PusherNode(parameter_overrides=params("pusher", {}))]
    import rclpy

    client_node = rclpy.create_node("goal_bench_user")
    action = ActionClient(client_node, PushToGoal, "push_to_goal")
    executor = MultiThreadedExecutor(num_threads=8)
    for n in nodes + [client_node]:
        executor.add_node(n)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()

    def wait(done, seconds: float) -> bool:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not done():
            time.sleep(0.02)
        return bool(done())

    out = {"source": source, "shape": f"{category}:{seed}", "outcome": "no_server", "pushes": 0}
    try:
        predictor = nodes[2]
        if not action.wait_for_server(timeout_sec=20.0):
            return out
        if not wait(lambda: tracked_id in predictor._features, 30.0):
            out["outcome"] = "no_feature"
            return out
        g = PushToGoal.Goal(object_id=tracked_id, position_tolerance=GOAL_TOLERANCE, yaw_tolerance=math.pi,
                            max_pushes=3)
        g.header.frame_id = "world"
        g.goal_pose = pose([goal[0], goal[1], 0.0], yaw_quaternion(0.0))
        sent = action.send_goal_async(g)
        if not wait(sent.done, 20.0) or not sent.result().accepted:
            out["outcome"] = "not_accepted"
            return out
        result = sent.result().get_result_async()
        if not wait(result.done, timeout):
            out["outcome"] = "timeout"
            return out
        r = result.result().result
        pos, q, *_ = sim.sim.state(sim.object_id)
        up = Rotation.from_quat(q).apply([0.0, 0.0, 1.0])
        tilt = math.degrees(math.acos(float(np.clip(up[2], -1.0, 1.0))))
        err = math.hypot(pos[0] - goal[0], pos[1] - goal[1])
        out.update(outcome=r.outcome, pushes=int(r.pushes), true_error_m=round(err, 4),
                   reported_error_m=round(float(r.position_error), 4), tilt_deg=round(tilt, 1),
                   success=bool(err <= GOAL_TOLERANCE and tilt < 45.0))
        return out
    finally:
        stop.set()
        thread.join(10.0)
        executor._work_tracker.wait(10.0)
        deadline = time.monotonic() + 5.0
        while not all(f.done() for f in list(executor._futures)) and time.monotonic() < deadline:
            time.sleep(0.01)
        executor.shutdown(timeout_sec=5.0)
        for n in nodes + [client_node]:
            n.destroy_node()


def squat_seed(category: str, seed: int) -> int:
    """The first seed from `seed` whose shape is no taller than 0.9 times its narrower footprint side and at least
    3 cm tall: a shape a push slides (taller ones the planner mostly refuses in both modes, which would measure
    nothing) and the camera sees above the table's cropped band."""
    from physdyn_ros.shapes import resolve_shape

    while True:
        v = np.asarray(resolve_shape(category, seed).vertices)
        size = v.max(0) - v.min(0)
        if 0.03 <= size[2] <= 0.9 * min(size[0], size[1]):
            return seed
        seed += 1


def goal_trials(n: int, seed: int, verbose: bool) -> dict:
    """n push_to_goal trials, each with state_source perception and with sim on the same shape, spawn and goal:
    the success fractions (None when n is 0)."""
    rng = np.random.default_rng(seed + 1000)
    results: dict[str, list[bool]] = {"perception": [], "sim": []}
    for k in range(n):
        category, shape_seed = GOAL_SHAPES[k % len(GOAL_SHAPES)]
        spawn = (*rng.uniform(-0.06, 0.06, 2), float(rng.uniform(-math.pi, math.pi)))
        turn, reach = rng.uniform(-math.pi, math.pi), rng.uniform(0.10, 0.18)
        goal = tuple(np.clip([spawn[0] + reach * math.cos(turn), spawn[1] + reach * math.sin(turn)],
                             -VIEW + 0.05, VIEW - 0.05))
        for source in ("perception", "sim"):
            trial = goal_trial(source, category, squat_seed(category, shape_seed + 10 * (k // len(GOAL_SHAPES))),
                               spawn, goal)
            results[source].append(bool(trial.get("success")))
            if verbose:
                print(f"  goal {k} ({source}): {trial}")
    return {s: (round(float(np.mean(v)), 3) if v else None) for s, v in results.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pushes", type=int, default=24)
    ap.add_argument("--rest-seconds", type=float, default=60.0)
    ap.add_argument("--resolution", type=int, nargs=2, default=(320, 240))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--track-com", choices=("footprint", "model"), default="footprint",
                    help="the perception node's track_com (where a track's centre of mass is taken)")
    ap.add_argument("--goals", type=int, default=16,
                    help="push_to_goal trials, each run with state_source perception and sim (0: none)")
    ap.add_argument("--depth-noise", type=float, default=0.0,
                    help="m: Gaussian depth noise along each ray at 1 m range, growing with the range squared (the "
                         "sim's renderer is exact)")
    ap.add_argument("--flying-pixels", type=float, default=0.0,
                    help="share of each cloud's points moved 1-6 cm farther along their ray (mixed pixels)")
    ap.add_argument("--steps-in", type=int, default=None,
                    help="tracked states after each onset fed to the model with perception's initial_state (default: "
                         "the predictor's steps_in in the perception overlay, what the suite does)")
    ap.add_argument("--objects", default=",".join(f"{c}:{n}" for _, c, n, _ in OBJECTS),
                    help="the three objects, category:seed each (default: %(default)s)")
    ap.add_argument("--verbose", action="store_true", help="a line per push and per goal trial")
    args = ap.parse_args()
    try:
        objects = parse_objects(args.objects)
    except ValueError as exc:
        ap.error(str(exc))
    if not (math.isfinite(args.depth_noise) and args.depth_noise >= 0.0 and 0.0 <= args.flying_pixels <= 1.0):
        ap.error(f"--depth-noise must be >= 0 m and --flying-pixels within [0, 1], got {args.depth_noise:g} and "
                 f"{args.flying_pixels:g}")

    import rclpy
    import torch
    from rclpy.parameter import Parameter

    from physdyn_ros.nodes.perception_node import PerceptionNode
    from physdyn_ros.predictor import Predictor
    from physdyn_ros.ros.cloud import cloud_to_xyz, xyz_to_cloud
    from physdyn_ros.ros.convert import ns_to_time, time_to_ns
    from physdyn_ros.ros.pending import PendingRefinement, states_after
    from physdyn_ros.ros.requests import observed_steps
    from physdyn_ros.shapes import resolve_shape
    from physdyn_ros.sim import SimConfig, Simulator
    from physdyn_ros.sim.camera import CameraSpec, DepthCamera
    from physdyn_ros.suite import parse_overrides, state_source_overlay

    torch.set_num_threads(1)
    rclpy.init()
    rng = np.random.default_rng(args.seed)
    noise_rng = np.random.default_rng([args.seed, 1])  # its own stream: the pushes stay those of the exact run
    phase_rng = np.random.default_rng([args.seed, 2])
    # the perception node as `physdyn up --state-source perception` runs it (its overlay's perception settings)
    overlay = parse_overrides("perception", state_source_overlay("perception").get("perception", []))
    node = PerceptionNode(parameter_overrides=[Parameter("single_object", value=False),
                                               Parameter("num_threads", value=1),
                                               Parameter("track_com", value=args.track_com)]
                          + [Parameter(k, value=v) for k, v in overlay.items()])
    predictor = Predictor.load(threads=1)
    steps_in = (args.steps_in if args.steps_in is not None else
                int(parse_overrides("predictor", state_source_overlay("perception").get("predictor", []))
                    .get("steps_in", 0)))
    spec = CameraSpec.make((0.6, 0.0, 0.45), (0.0, 0.0, 0.05), args.resolution, 60.0)
    rest_frames = int(round(args.rest_seconds * 15))
    frames = rest_frames + args.pushes * FRAMES_PER_PUSH + 15
    truth: list[dict] = []  # per frame: sim id -> (pos, quat, lin, ang)
    tracked: list[dict] = []  # per frame: track id -> ObjectState
    onsets: list[tuple[int, object]] = []  # (frame, ObjectState)
    features: dict[str, object] = {}  # track id -> latest ShapeFeature
    feature_at: list[dict] = []
    pushes: list[dict] = []
    frame_ms: list[float] = []
    n_points: list[int] = []
    radii: dict[str, float] = {}
    with Simulator(SimConfig(friction=0.5, collision="hull")) as sim:
        for oid, cat, seed, xy in objects:
            shape = resolve_shape(cat, seed)
            sim.spawn(shape, xy=xy, yaw=float(rng.uniform(-math.pi, math.pi)), object_id=oid)
            radii[oid] = float(np.max(np.linalg.norm(shape.vertices[:, :2], axis=1)))  # origin: the COM
        camera = DepthCamera(sim)
        for k in range(frames):
            if k >= rest_frames and (k - rest_frames) % FRAMES_PER_PUSH == 0 and len(pushes) < args.pushes:
                oid, v = free_push(sim, rng, radii)
                w = np.array([0.0, 0.0, float(rng.uniform(-3.0, 3.0))])
                # a push at any instant between two clouds: `lead` physics steps before this one
                lead = int(phase_rng.integers(0, sim.config.substeps))
                for _ in range(sim.config.substeps - lead):
                    sim.client.stepSimulation()
                sim.set_velocity(v, w, oid)
                for _ in range(lead):
                    sim.client.stepSimulation()
                pushes.append({"frame": k, "id": oid, "v": v, "w": w,
                               "t_ns": 10**9 + k * DT_NS - lead * DT_NS // sim.config.substeps})
            elif k:
                sim.step()
            truth.append({oid: tuple(np.asarray(a, float) for a in s) for oid, s in sim.states().items()})
            t0 = time.perf_counter()
            points = camera.render(spec)
            if args.depth_noise > 0 or args.flying_pixels > 0:
                points = sensor_noise(points, spec.eye, noise_rng, args.depth_noise, args.flying_pixels)
            n_points.append(len(points))
            msg = xyz_to_cloud(points, "world", ns_to_time(10**9 + k * DT_NS))
            feats, _, _ = node.process(msg)
            frame_ms.append(1e3 * (time.perf_counter() - t0))
            tracked.append({s.object_id: s for s in node.states})
            onsets += [(k, s) for s in node.onsets]
            for f in feats:
                features[f.object_id] = f
            feature_at.append(dict(features))
    # track ids -> sim ids, by the nearest object on the first cloud where each object is some track's nearest (an
    # object split in two has two tracks: both are its own, and it is never judged kept)
    def nearest(k: int) -> dict:
        return {tid: min(truth[k], key=lambda oid: np.linalg.norm(xyz(s.pose.position)[:2] - truth[k][oid][0][:2]))
                for tid, s in tracked[k].items()}

    first = next(i for i in range(len(tracked)) if len(set(nearest(i).values())) == len(objects))
    match = nearest(first)
    q_first = {tid: quat(s) for tid, s in tracked[first].items()}
    pos_rest, pos_moving, rot_rest, rot_moving = [], [], [], []
    per_object: dict[str, dict[str, list[float]]] = {oid: {"rest": [], "moving": [], "turn": [], "prediction": []}
                                                     for oid, *_ in objects}
    for k in range(first, frames):
        for tid, s in tracked[k].items():
            oid = match.get(tid)
            if oid is None:
                continue
            p, q, lin, _ = truth[k][oid]
            err = 1e3 * float(np.linalg.norm(xyz(s.pose.position) - p))
            # the rotation since the first cloud, tracked against true (the frames' conventions cancel)
            rerr = math.degrees(relative_error(quat(s), q_first[tid], q, truth[first][oid][1]))
            moving = float(np.linalg.norm(lin[:2])) > MOVING
            (pos_moving if moving else pos_rest).append(err)
            per_object[oid]["moving" if moving else "rest"].append(err)
            if moving:
                per_object[oid]["turn"].append(rerr)
            (rot_moving if moving else rot_rest).append(rerr)
    inverse = {oid: tid for tid, oid in match.items()}
    detected, delays, speed_err, spin_err, pred_ratio_perc, pred_ratio_true, kept = [], [], [], [], [], [], []
    used = set()
    for n, p in enumerate(pushes):
        tid = inverse.get(p["id"])
        hits = [(i, (k, s)) for i, (k, s) in enumerate(onsets) if s.object_id == tid and i not in used
                and -1.0 <= late(s, p) <= 5.0]
        end = min(p["frame"] + FRAMES_PER_PUSH - 1, frames - 1)
        rest_pos = truth[end][p["id"]][0]
        # judged on the push window's last cloud that shows every object (one cloud may miss a sparse object)
        judged = next((j for j in range(end, end - 5, -1) if len(tracked[j]) == len(objects)), end)
        kept.append(len(tracked[judged]) == len(objects)
                    and all(oid == match.get(t) for t, oid in nearest(judged).items()))
        if args.verbose:
            near = [(frame_of(o), o.object_id) for _, o in onsets
                    if abs(frame_of(o) - p["frame"]) < FRAMES_PER_PUSH]
            print(f"  push {n}: {p['id']} (track {tid}) at frame {p['frame']}, |v| {np.linalg.norm(p['v']):.2f}; "
                  f"onsets near: {near}; tracks at rest: {sorted(tracked[end])}, kept {kept[-1]}")
        if not hits:
            detected.append(False)
            continue
        i, (k_on, s) = hits[0]
        used.add(i)
        detected.append(True)
        delays.append(late(s, p))
        v_est = xyz(s.twist.linear)
        speed_err.append(abs(np.linalg.norm(v_est[:2]) - np.linalg.norm(p["v"][:2])) / np.linalg.norm(p["v"][:2]))
        spin_err.append(float(np.linalg.norm(xyz(s.twist.angular) - p["w"])))
        feat = feature_at[max(p["frame"] - 1, 0)].get(tid)
        if feat is None:
            continue
        cloud = cloud_to_xyz(feat.points)
        code = predictor.encode(cloud)
        # the tracked states after the onset, as the predictor node refines with them (ros/pending.refine)
        t_on = time_to_ns(s.header.stamp)
        f_on = max(frame_of(s), 0)  # states published before the onset was (detection delay) count too
        after = states_after([tracked[j][tid] for j in range(f_on, min(f_on + steps_in + 2, frames))
                              if tid in tracked[j]], t_on, DT_NS, steps_in)
        onset = PendingRefinement(tid, t_on, xyz(s.pose.position), quat(s), v_est, xyz(s.twist.angular), feat, 0.0)
        est = predictor.rollout(code, v_est, xyz(s.twist.angular), 60, position=xyz(s.pose.position),
                                orientation=quat(s), observed=observed_steps(after, onset) if after else None)
        p0, q0, _, _ = truth[max(p["frame"] - 1, 0)][p["id"]]
        ref = predictor.rollout(code, p["v"], p["w"], 60, position=p0, orientation=q0)
        pred_ratio_perc.append(float(np.linalg.norm(est.positions[-1][:2] - rest_pos[:2])))
        pred_ratio_true.append(float(np.linalg.norm(ref.positions[-1][:2] - rest_pos[:2])))
        per_object[p["id"]]["prediction"].append(pred_ratio_perc[-1] / max(pred_ratio_true[-1], 1e-3))
    false_rest = sum(1 for k, _ in onsets if k < rest_frames)

    def truly_moved(s) -> bool:
        """The onset's object moved (true speed above MOVING within 3 frames of its stamp): a collision the
        push's clearance missed, or motion after its push; a correct detection, not a false onset."""
        f, oid = frame_of(s), match.get(s.object_id)
        return oid is not None and any(float(np.linalg.norm(truth[j][oid][2][:2])) > MOVING
                                       for j in range(max(0, f - 3), min(frames, f + 4)))

    unmatched = [s for i, (_, s) in enumerate(onsets) if i not in used]
    unpushed = sum(1 for s in unmatched if truly_moved(s))
    false_all = len(unmatched) - unpushed
    cost = perception_100k_ms()
    node.destroy_node()
    goal_success = goal_trials(args.goals, args.seed, args.verbose) if args.goals > 0 else {}
    rclpy.shutdown()

    def med(x) -> float | None:
        return round(float(np.median(x)), 3) if len(x) else None

    def p90(x) -> float | None:
        return round(float(np.percentile(x, 90)), 3) if len(x) else None

    def cm(x) -> float | None:
        return round(100 * float(np.median(x)), 2) if len(x) else None

    # from the unrounded medians: med() keeps whole millimetres of errors of a few millimetres
    ratio = (float(np.median(pred_ratio_perc)) / float(np.median(pred_ratio_true))
             if pred_ratio_true and np.median(pred_ratio_true) > 0 else None)
    out = {
        "position_error_rest_mm": med(pos_rest), "position_error_rest_p90_mm": p90(pos_rest),
        "position_error_moving_mm": med(pos_moving), "position_error_moving_p90_mm": p90(pos_moving),
        "orientation_error_rest_deg": med(rot_rest), "orientation_error_moving_deg": med(rot_moving),
        "onset_detected_fraction": round(float(np.mean(detected)), 3) if detected else None,
        "onset_delay_frames": med(delays), "false_onsets_at_rest": false_rest, "false_onsets": false_all,
        "onsets_unpushed_motion": unpushed,
        "rest_seconds": args.rest_seconds, "initial_speed_error_frac": med(speed_err),
        "initial_spin_error_rad_s": med(spin_err),
        "prediction_error_ratio": round(ratio, 3) if ratio is not None else None,
        "prediction_error_perception_cm": cm(pred_ratio_perc), "prediction_error_truth_cm": cm(pred_ratio_true),
        "id_kept_fraction": round(float(np.mean(kept)), 3) if kept else None, "pushes": len(pushes),
        "perception_p50_ms_100k": round(cost, 2), "camera_frame_p50_ms": med(frame_ms),
        "points_per_cloud": med(n_points), "push_to_goal_success_perception": goal_success.get("perception"),
        "push_to_goal_success_truth": goal_success.get("sim"), "push_to_goal_trials": args.goals,
        "steps_in": steps_in, "depth_noise_m": args.depth_noise, "flying_pixels": args.flying_pixels,
    }
    print(f"{len(pushes)} pushes after {args.rest_seconds:g} s at rest; {args.resolution[0]} x {args.resolution[1]} "
          f"camera clouds at 15 Hz; three objects")
    for key, value in out.items():
        print(f"  {key}: {value}")
    for oid, category, *_ in objects:
        figures = per_object[oid]
        print(f"  {category} ({oid}): position median {med(figures['rest'])} mm at rest, {med(figures['moving'])} mm "
              f"moving, orientation {med(figures['turn'])} deg moving; prediction error over the true state's, "
              f"median per push {med(figures['prediction'])} "
              f"({len(figures['prediction'])} pushes)")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
