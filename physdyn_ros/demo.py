"""``physdyn demo``: start the suite, push several objects, compare the predicted and the true motion.

One command on the shipped model (or --model PATH). The sim runs as fast as possible (real_time_factor 0). For
each push: spawn an object (procedural categories and pybullet_data meshes the model never saw), wait for its
shape feature, push it through the sim's `push` service, collect the prediction the predictor publishes for the
push's initial_twist and the true trajectory the sim publishes on object_state, and print the final-pose errors.
Writes DIR/demo.png (top view, predicted vs true), DIR/results.json and the nodes' logs in DIR/logs/.
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


@dataclass
class PushResult:
    index: int
    shape: str
    category: str
    impulse: list[float]
    initial_lin_vel: list[float]
    initial_ang_vel: list[float]
    predicted_final: list[float]  # x, y, z
    true_final: list[float]
    position_error_cm: float
    rotation_error_deg: float
    mean_position_error_cm: float
    topple_probability: float
    toppled: bool
    predicted_xy: list[list[float]]
    true_xy: list[list[float]]


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
        from .nodes.sim_node import STATE_QOS
        from .srv import PushObject, SpawnObject

        self.node = rclpy.create_node("physdyn_demo")
        self.lock = threading.Lock()
        self.features: list = []
        self.states: list = []
        self.trajs: list = []
        self.twists: list = []
        self.node.create_subscription(ShapeFeature, "shape_feature", self._add(self.features), FEATURE_QOS)
        self.node.create_subscription(ObjectState, "object_state", self._add(self.states), STATE_QOS)
        self.node.create_subscription(PredictedTrajectory, "predicted_trajectory", self._add(self.trajs), LATCHED)
        self.node.create_subscription(TwistStamped, "initial_twist", self._add(self.twists), 10)
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
    from .ros.convert import quat_angle, time_to_ns
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
    pred_q = [[s.pose.orientation.x, s.pose.orientation.y, s.pose.orientation.z, s.pose.orientation.w]
              for s in traj.states]
    true_pos = np.array(true_pos)
    n = min(len(pred_pos), len(true_pos))
    err = np.linalg.norm(pred_pos[:n] - true_pos[:n], axis=1)
    return PushResult(
        index=index, shape=shape, category=category, impulse=impulse.round(4).tolist(),
        initial_lin_vel=[res.initial_twist.linear.x, res.initial_twist.linear.y, res.initial_twist.linear.z],
        initial_ang_vel=[res.initial_twist.angular.x, res.initial_twist.angular.y, res.initial_twist.angular.z],
        predicted_final=pred_pos[n - 1].tolist(), true_final=true_pos[n - 1].tolist(),
        position_error_cm=float(100 * err[-1]), rotation_error_deg=math.degrees(quat_angle(pred_q[n - 1],
                                                                                            true_q[n - 1])),
        mean_position_error_cm=float(100 * err.mean()), topple_probability=float(traj.topple_probability),
        toppled=bool(any(s.toppled for s in true_states)),
        predicted_xy=pred_pos[:n, :2].round(5).tolist(), true_xy=true_pos[:n, :2].round(5).tolist())


def plot(results: list[PushResult], path: Path, model_id: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = min(3, len(results))
    rows = math.ceil(len(results) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.0 * rows), squeeze=False)
    for ax in axes.flat[len(results):]:
        ax.axis("off")
    for r, ax in zip(results, axes.flat):
        t, p = np.array(r.true_xy), np.array(r.predicted_xy)
        ax.plot(100 * t[:, 0], 100 * t[:, 1], "-", color="k", lw=2, label="true (pybullet)")
        ax.plot(100 * p[:, 0], 100 * p[:, 1], "--", color="tab:red", lw=2, label="predicted")
        ax.plot(100 * t[0, 0], 100 * t[0, 1], "o", color="tab:green", label="start")
        ax.plot(100 * t[-1, 0], 100 * t[-1, 1], "s", color="k")
        ax.plot(100 * p[-1, 0], 100 * p[-1, 1], "s", color="tab:red")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"{r.index}: {r.shape}\nfinal error {r.position_error_cm:.1f} cm, {r.rotation_error_deg:.0f} deg",
                     fontsize=9)
        ax.set_xlabel("x (cm)")
        ax.set_ylabel("y (cm)")
        ax.grid(alpha=0.3)
    axes.flat[0].legend(fontsize=7, loc="best")
    fig.suptitle(f"physdyn demo, model {model_id}: top view, {len(results[0].true_xy) - 1} steps of 1/15 s",
                 fontsize=10)
    fig.tight_layout()
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
        header = (f"{'#':>2} {'object':<28} {'predicted final (x, y) m':>26} {'true final (x, y) m':>22} "
                  f"{'err cm':>7} {'err deg':>8} {'topple p':>8}")
        print(header)
        for i, (category, seed) in enumerate(push_plan(args.pushes, args.seed), start=1):
            r = run_push(client, i, category, seed, rng, args.horizon)
            results.append(r)
            print(f"{i:>2} {r.shape:<28} ({r.predicted_final[0]:+.3f}, {r.predicted_final[1]:+.3f}){'':>9}"
                  f"({r.true_final[0]:+.3f}, {r.true_final[1]:+.3f}){'':>5} {r.position_error_cm:>7.1f} "
                  f"{r.rotation_error_deg:>8.1f} {r.topple_probability:>8.2f}{'  (toppled)' if r.toppled else ''}",
                  flush=True)
            dead = suite.dead()
            if dead is not None:
                raise RuntimeError(f"node '{dead.name}' died (see {out / 'logs' / (dead.name + '.log')})")
        pos = np.array([r.position_error_cm for r in results])
        rot = np.array([r.rotation_error_deg for r in results])
        model_id = client.trajs[-1].model_id if client.trajs else "?"
        print(f"mean final error over {len(results)} pushes: {pos.mean():.1f} cm, {rot.mean():.1f} deg "
              f"(median {np.median(pos):.1f} cm, {np.median(rot):.1f} deg)")
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
