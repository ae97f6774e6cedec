"""``physdyn demo``: start the suite, push several objects, compare the predicted and the true motion.

One command on the shipped model (or --model PATH). The sim runs as fast as possible (real_time_factor 0). For
each push: spawn an object (procedural categories and pybullet_data meshes the model never saw), wait for its
shape feature, push it through the sim's `push` service, collect the prediction the predictor publishes for the
push's initial_twist and the true trajectory the sim publishes on object_state, and print the errors.

What is scored is what the model claims: where the object comes to rest and whether it topples. A push that
topples is scored up to the topple (the last upright frame); where a toppled object rolls afterwards is not
predicted and not scored. Each push gets a verdict: GOOD within 2 cm and 10 deg with the topple predicted right
(the planner's tolerance), FAIR within 5 cm and 30 deg with the topple right, POOR otherwise.
Writes DIR/demo.png (top view at one scale for every panel: outlines and headings at the start, the predicted
and the true pose, a scale bar, the verdicts), DIR/results.json and the nodes' logs in DIR/logs/.
"""
from __future__ import annotations

import argparse
import json
import math
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

HORIZON = 60
#: A predicted topple: the trajectory's topple probability above this.
TOPPLE_THRESHOLD = 0.5
#: (verdict, position cm, rotation deg): the first whose bounds hold, with the topple predicted right.
VERDICTS = (("GOOD", 2.0, 10.0), ("FAIR", 5.0, 30.0))
OUTLINE_POINTS = 400


@dataclass
class PushResult:
    index: int
    shape: str
    category: str
    impulse: list[float]
    initial_lin_vel: list[float]
    initial_ang_vel: list[float]
    predicted_final: list[float]  # x, y, z at the scored step
    true_final: list[float]
    position_error_cm: float  # at the scored step: the last, or the last upright one of a push that toppled
    rotation_error_deg: float
    mean_position_error_cm: float  # over steps 0..scored
    scored_step: int
    topple_probability: float
    predicted_topple: bool
    toppled: bool
    true_topple_step: int  # first step tilted over 45 deg; -1 when it stayed upright
    verdict: str
    predicted_xy: list[list[float]]
    true_xy: list[list[float]]
    predicted_quat: list[float]  # x, y, z, w at the scored step
    true_quat: list[float]
    start_quat: list[float]
    outline: list[list[float]]  # surface points in the object frame (centre of mass, body axes), m


def verdict(position_cm: float, rotation_deg: float, topple_right: bool) -> str:
    for name, cm, deg in VERDICTS:
        if topple_right and position_cm <= cm and rotation_deg <= deg:
            return name
    return "POOR"


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
        from .nodes.perception_node import FEATURE_QOS
        from .nodes.predictor_node import LATCHED
        from sensor_msgs.msg import PointCloud2

        from .nodes.sim_node import CLOUD_QOS, STATE_QOS
        from .srv import PushObject, SpawnObject

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
        self.spawn = self.node.create_client(SpawnObject, "spawn_object")
        self.push = self.node.create_client(PushObject, "push")
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
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def call(self, client, request, timeout: float = 60.0):
        if not client.wait_for_service(timeout_sec=timeout):
            raise RuntimeError(f"service {client.srv_name} is not available")
        future = client.call_async(request)
        deadline = time.monotonic() + timeout
        while not future.done():
            if time.monotonic() > deadline:
                raise RuntimeError(f"no answer from {client.srv_name} within {timeout:.0f} s")
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


def run_push(c: DemoClient, index: int, category: str, shape_seed: int, rng: np.random.Generator,
             horizon: int) -> PushResult:
    from .ros.convert import time_to_ns
    from .srv import PushObject, SpawnObject

    yaw = float(rng.uniform(-math.pi, math.pi))
    spawned = c.call(c.spawn, SpawnObject.Request(category=category, shape_seed=shape_seed, yaw=yaw))
    if not spawned.success:
        raise RuntimeError(spawned.message)
    shape = spawned.message.split(": ", 1)[-1].split(" (")[0]
    # Clouds stamped at or after the first state published after the spawn show the new object.
    n_states = len(c.states)
    first = c.wait(lambda: c.states[n_states:] and c.states[n_states], 10, "the new object's state")
    t_spawn = time_to_ns(first.header.stamp)
    c.wait(lambda: any(time_to_ns(f.header.stamp) >= t_spawn for f in c.features), 30,
           f"the shape feature of {shape} (is the perception node running?)")
    cloud = c.wait(lambda: next((m for m in reversed(c.clouds) if time_to_ns(m.header.stamp) >= t_spawn), None),
                   30, f"the cloud of {shape}")
    outline = body_points(cloud, first.pose, rng)
    # A push through a point beside the centre of mass: it slides and spins; sometimes it topples.
    speed = float(rng.uniform(0.3, 1.2))
    az = float(rng.uniform(-math.pi, math.pi))
    d = np.array([math.cos(az), math.sin(az), 0.0])
    side = np.array([-d[1], d[0], 0.0])
    com = first.pose.position
    he = np.array([spawned.half_extents.x, spawned.half_extents.y, spawned.half_extents.z])
    point = np.array([com.x, com.y, com.z]) + side * rng.uniform(-0.5, 0.5) * he[:2].min() \
        + np.array([0, 0, rng.uniform(0.0, 0.6) * he[2]])
    impulse = spawned.mass * speed * d
    req = PushObject.Request()
    req.impulse.x, req.impulse.y, req.impulse.z = (float(v) for v in impulse)
    req.point.x, req.point.y, req.point.z = (float(v) for v in point)
    n_twists = len(c.twists)
    res = c.call(c.push, req)
    if not res.success:
        raise RuntimeError(res.message)
    twist = c.wait(lambda: c.twists[n_twists:] and c.twists[n_twists], 10, "initial_twist")
    t0 = time_to_ns(twist.header.stamp)
    traj = c.wait(lambda: next((t for t in reversed(c.trajs) if time_to_ns(t.header.stamp) == t0), None), 30,
                  "the predicted trajectory (see logs/predictor.log)")
    dt_ns = time_to_ns(traj.states[1].header.stamp) - t0 if len(traj.states) > 1 else int(1e9 / 15)
    end_ns = t0 + horizon * dt_ns

    def truth():
        after = [s for s in c.states if time_to_ns(s.header.stamp) > t0]
        # the sim holds a settled object exactly still (zero twist): the trajectory is complete then
        done = any(time_to_ns(s.header.stamp) >= end_ns or (s.twist.linear.x == s.twist.linear.y ==
                   s.twist.linear.z == s.twist.angular.x == s.twist.angular.y == s.twist.angular.z == 0.0)
                   for s in after)
        return done and [s for s in c.states if t0 <= time_to_ns(s.header.stamp) <= end_ns]

    true_states = c.wait(truth, 60, "the true trajectory on object_state")
    by_step = {round((time_to_ns(s.header.stamp) - t0) / dt_ns): s for s in true_states}
    true_pos, true_q, last = [], [], by_step[0]
    for k in range(horizon + 1):  # frames after rest repeat the rest pose (the dataset convention)
        last = by_step.get(k, last)
        true_pos.append([last.pose.position.x, last.pose.position.y, last.pose.position.z])
        o = last.pose.orientation
        true_q.append([o.x, o.y, o.z, o.w])
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
        index=index, shape=shape, category=category, impulse=impulse.round(4).tolist(),
        initial_lin_vel=[res.initial_twist.linear.x, res.initial_twist.linear.y, res.initial_twist.linear.z],
        initial_ang_vel=[res.initial_twist.angular.x, res.initial_twist.angular.y, res.initial_twist.angular.z],
        predicted_final=pred_pos[k].tolist(), true_final=true_pos[k].tolist(), **sc,
        topple_probability=float(traj.topple_probability), predicted_topple=predicted_topple, toppled=toppled,
        verdict=verdict(sc["position_error_cm"], sc["rotation_error_deg"], predicted_topple == toppled),
        predicted_xy=pred_pos[:n, :2].round(5).tolist(), true_xy=true_pos[:n, :2].round(5).tolist(),
        predicted_quat=pred_q[k].tolist(), true_quat=true_q[k].tolist(), start_quat=true_q[0].tolist(),
        outline=outline.round(5).tolist())


def body_points(cloud, pose, rng: np.random.Generator) -> np.ndarray:
    """The object's surface points (table frame cloud) in its body frame at `pose`, at most OUTLINE_POINTS."""
    from scipy.spatial.transform import Rotation

    from .ros.cloud import cloud_to_xyz

    pts = cloud_to_xyz(cloud, max_points=OUTLINE_POINTS, rng=rng).astype(np.float64)
    c = np.array([pose.position.x, pose.position.y, pose.position.z])
    q = [pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w]
    return Rotation.from_quat(q).inv().apply(pts - c)


def nice_length(span_cm: float) -> float:
    """A round scale-bar length (1, 2 or 5 times a power of ten cm) about a quarter of `span_cm`."""
    target = max(span_cm / 4.0, 1e-3)
    base = 10.0 ** math.floor(math.log10(target))
    return max(m * base for m in (1.0, 2.0, 5.0) if m * base <= target)


def footprint(outline_body: np.ndarray, position, quat) -> np.ndarray:
    """Closed 2-D convex outline (cm) of the object's points posed at (position, quat), seen from above."""
    from scipy.spatial import ConvexHull
    from scipy.spatial.transform import Rotation

    xy = (Rotation.from_quat(quat).apply(outline_body) + np.asarray(position))[:, :2] * 100.0
    try:
        hull = xy[ConvexHull(xy).vertices]
    except Exception:  # noqa: BLE001 - a degenerate outline (a line seen from above) is drawn as its points
        hull = xy
    return np.vstack([hull, hull[:1]])


def heading(outline_body: np.ndarray, position, quat) -> tuple[np.ndarray, np.ndarray]:
    """Arrow (start, delta) in cm along the object's body x axis, as long as the object's reach."""
    from scipy.spatial.transform import Rotation

    reach = float(np.linalg.norm(outline_body[:, :2], axis=1).max()) if len(outline_body) else 0.05
    d = Rotation.from_quat(quat).apply([1.0, 0.0, 0.0])[:2]
    return np.asarray(position)[:2] * 100.0, d / max(np.linalg.norm(d), 1e-9) * reach * 100.0


def summary(results: list[PushResult]) -> str:
    good = sum(r.verdict == "GOOD" for r in results)
    fair = sum(r.verdict == "FAIR" for r in results)
    right = sum(r.predicted_topple == r.toppled for r in results)
    return (f"{good} of {len(results)} pushes GOOD (within 2 cm and 10 deg), {fair} FAIR (5 cm, 30 deg); "
            f"topple predicted right in {right} of {len(results)}")


def plot(results: list[PushResult], path: Path, model_id: str) -> None:
    """Top views at ONE scale: outlines and headings at the start (grey), the true (black) and the predicted
    (red, dashed) pose at the scored step; the true path after a topple is dotted and not scored."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"GOOD": "tab:green", "FAIR": "tab:orange", "POOR": "tab:red"}
    panels = []
    for r in results:
        t, p = 100 * np.array(r.true_xy), 100 * np.array(r.predicted_xy)
        body = np.array(r.outline).reshape(-1, 3)
        k = r.scored_step
        shapes = {"start": footprint(body, r.true_xy[0] + [0.0], r.start_quat),
                  "true": footprint(body, r.true_final, r.true_quat),
                  "pred": footprint(body, r.predicted_final, r.predicted_quat)}
        scored = np.vstack([t[: k + 1], p[: k + 1]] + list(shapes.values()))
        panels.append((r, t, p, body, shapes, scored))
    # one scale for every panel: the largest scored extent decides
    half = 0.55 * max(float(np.ptp(sc, axis=0).max()) for *_, sc in panels) + 1.0
    bar = nice_length(2 * half)
    cols = min(3, len(results))
    rows = math.ceil(len(results) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 4.9 * rows), squeeze=False)
    for ax in axes.flat[len(results):]:
        ax.axis("off")
    for (r, t, p, body, shapes, scored), ax in zip(panels, axes.flat):
        k = r.scored_step
        centre = 0.5 * (scored.min(axis=0) + scored.max(axis=0))
        ax.fill(*shapes["start"].T, color="0.85", zorder=1, label="start")
        ax.plot(*shapes["true"].T, "-", color="k", lw=1.6, zorder=3, label="true pose")
        ax.plot(*shapes["pred"].T, "--", color="tab:red", lw=1.6, zorder=4, label="predicted pose")
        for (pos, q), colour in (((r.true_xy[0] + [0.0], r.start_quat), "0.45"),
                                 ((r.true_final, r.true_quat), "k"), ((r.predicted_final, r.predicted_quat),
                                                                      "tab:red")):
            start, delta = heading(body, pos, q)
            ax.annotate("", start + delta, start, arrowprops=dict(arrowstyle="->", color=colour, lw=1.3), zorder=5)
        ax.plot(*t[: k + 1].T, "-", color="k", lw=1.0, zorder=3)
        ax.plot(*p[: k + 1].T, "--", color="tab:red", lw=1.0, zorder=4)
        if r.toppled:
            ax.plot(*t[k:].T, ":", color="0.4", lw=1.0, zorder=2, label="after the topple (not scored)")
            ax.plot(*t[r.true_topple_step], "x", color="k", ms=9, mew=2, zorder=6, label="true topple")
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        x0, y0 = centre[0] - 0.9 * half, centre[1] - 0.88 * half
        ax.plot([x0, x0 + bar], [y0, y0], "-", color="k", lw=3, solid_capstyle="butt")
        ax.text(x0 + bar / 2, y0 + 0.04 * half, f"{bar:g} cm", ha="center", va="bottom", fontsize=8)
        when = (f"at {k / 15:.1f} s, the last upright frame" if r.toppled else f"at {k / 15:.1f} s (the end)")
        topple = (f"topple: predicted {'yes' if r.predicted_topple else 'no'} (p {r.topple_probability:.2f}), "
                  f"true {'yes' if r.toppled else 'no'}")
        ax.set_title(f"{r.index}: {r.shape}   {r.verdict}\nerror {r.position_error_cm:.1f} cm, "
                     f"{r.rotation_error_deg:.0f} deg {when}\n{topple}", fontsize=8.5,
                     color=colours[r.verdict])
    from matplotlib.lines import Line2D

    handles = {}
    for ax in axes.flat[: len(results)]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    handles["heading (body x axis)"] = Line2D([], [], color="k", marker=">", lw=1.0, markevery=[1])
    handles["path of the centre of mass"] = Line2D([], [], color="k", lw=1.0)
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=min(7, len(handles)), fontsize=8,
               frameon=False)
    fig.suptitle(f"physdyn demo, model {model_id}: top view, every panel at the same scale, "
                 f"{len(results[0].true_xy) - 1} steps of 1/15 s\n{summary(results)}", fontsize=10)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


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
    parser.add_argument("--pushes", type=int, default=6, help="number of pushes (objects), default 6")
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
    if not 1 <= args.horizon <= 150:
        raise ValueError("--horizon must be in 1..150")
    model = Path(args.model).expanduser().resolve() if args.model else DEFAULT_MODEL
    if not model.is_file():
        raise FileNotFoundError(f"model {model} does not exist" + ("" if args.model else
                                "; the shipped model is missing: pass --model PATH to a checkpoint"))
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    overrides = {
        "sim": ["real_time_factor:=0.0", "publish_cloud_rate:=5.0", "max_push_time:=6.0", "rate:=15.0"],
        "perception": [f"model_path:={model}"],
        "predictor": [f"model_path:={model}", f"horizon:={args.horizon}", "max_feature_age:=30.0"],
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
        header = (f"{'#':>2} {'object':<28} {'predicted (x, y) m':>19} {'true (x, y) m':>17} {'at s':>5} "
                  f"{'err cm':>7} {'err deg':>8} {'topple p':>8} {'toppled':>7} verdict")
        print(header)
        for i, (category, seed) in enumerate(push_plan(args.pushes, args.seed), start=1):
            r = run_push(client, i, category, seed, rng, args.horizon)
            results.append(r)
            print(f"{i:>2} {r.shape:<28} ({r.predicted_final[0]:+.3f}, {r.predicted_final[1]:+.3f})  "
                  f"({r.true_final[0]:+.3f}, {r.true_final[1]:+.3f}) {r.scored_step / 15:>5.1f} "
                  f"{r.position_error_cm:>7.1f} {r.rotation_error_deg:>8.1f} {r.topple_probability:>8.2f} "
                  f"{'yes' if r.toppled else 'no':>7} {r.verdict}", flush=True)
            dead = suite.dead()
            if dead is not None:
                raise RuntimeError(f"node '{dead.name}' died (see {out / 'logs' / (dead.name + '.log')})")
        pos = np.array([r.position_error_cm for r in results])
        rot = np.array([r.rotation_error_deg for r in results])
        model_id = client.trajs[-1].model_id if client.trajs else "?"
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
