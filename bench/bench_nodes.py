#!/usr/bin/env python3
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
"""Latency and throughput of the perception and predictor nodes, as separate processes over DDS (loopback).

    .venv/bin/python bench/bench_nodes.py [--model PATH] [--samples 100] [--clients 8] [--domain 42]
        [--predictor-param NAME:=VALUE ...]

The bench plays the world: it starts perception_node and predictor_node with config/suite.yaml (as `physdyn
up --nodes perception,predictor` does) and publishes the clouds, object states and twists itself.
* twist -> trajectory: wall time from publishing an initial_twist (with the object_state of the same stamp
  already published) to receiving the predicted_trajectory stamped with it (60-step horizon).
* service round trip: predict_trajectory by object_id, 60 steps, p50 / p99, one client, sequential; and where
  it goes: the node's time in its callback (from the response message), the response's CDR serialization and
  deserialization (timed in this process), and the CPU time per request of the node's process and of this client
  process (/proc and process_time over the sequential requests; the rest of a round trip is DDS and waiting).
  The client waits on an Event set by the future's done-callback (no polling), its node has no parameter
  services and only the clients it uses: a lean Python client.
* perception: a 100k-point cloud published on `cloud` -> its ShapeFeature received (DDS transfer of 1.6 MB +
  preprocessing + encoding), p50 / p99; and preprocessing + encoding alone, in this process.
* concurrency: --clients clients, each sending requests back to back; requests per second and the number
  of requests not answered (must be 0).
The last line is one JSON object: service_p50_ms, service_p99_ms, service_callback_p50_ms, response_serialize_ms,
response_deserialize_ms, node_cpu_per_request_ms, client_cpu_per_request_ms, twist_to_traj_p50_ms,
twist_to_traj_p99_ms, clients8_req_per_s, clients8_lost, clients8_lost_default_qos, twists_lost,
perception_dds_p50_ms, perception_dds_dropped, perception_local_p50_ms, load_average.
A lost sample is counted, never a traceback.
Without a shipped model the default architecture (config/model_default.yaml) is timed with random weights.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

HORIZON = 60
T_BASE = 2_000 * 10**9  # stamps used by the bench, ns


def random_weights_checkpoint(path: Path) -> None:
    import torch

    from physdyn_ros.learn.checkpoint import save_checkpoint
    from physdyn_ros.learn.model import STAT_KEYS, DynamicsModel, ModelConfig
    from physdyn_ros.learn.train import load_config

    cfg = load_config(ROOT / "config" / "model_default.yaml")
    torch.manual_seed(0)
    stats = dict(zip(STAT_KEYS, (0.5, 8.0, 0.2, 4.0, 0.03, 0.5, 0.15)))
    save_checkpoint(path, model=DynamicsModel(ModelConfig.from_dict(cfg["model"]), stats), config=cfg,
                    dataset={}, include_rng=False)


def box_cloud(n: int, rng: np.random.Generator) -> np.ndarray:
    half = np.array([0.05, 0.03, 0.04])
    p = rng.uniform(-1, 1, (n, 3)) * half
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.sign(rng.uniform(-1, 1, n)) * half[axis]
    return (p + (0.2, 0.1, 0.04) + rng.normal(0, 0.001, (n, 3))).astype(np.float32)


def p(samples: list[float], q: float) -> float | None:
    return round(float(np.percentile(np.asarray(samples) * 1e3, q)), 3) if samples else None


def process_cpu(pid: int | None) -> float | None:
    """CPU seconds (user + system, all threads) a process has used so far, from /proc (None where unreadable)."""
    if pid is None:
        return None
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def wire_costs(msg, cls, repeats: int = 30) -> tuple[list[float], list[float]]:
    """CPU seconds to serialize `msg` and to deserialize its bytes as `cls` (rclpy.serialization, as the
    executors do), measured in this process: what a round trip spends in message conversion."""
    if msg is None:
        return [], []
    from rclpy.serialization import deserialize_message, serialize_message

    data = serialize_message(msg)
    ser, deser = [], []
    for _ in range(repeats):
        t = time.thread_time()
        serialize_message(msg)
        ser.append(time.thread_time() - t)
        t = time.thread_time()
        deserialize_message(data, cls)
        deser.append(time.thread_time() - t)
    return ser, deser


def callback_seconds(message: str) -> float | None:
    """The node's own time in the service callback, from its response message ("60 steps in 3.2 ms")."""
    try:
        return float(message.rsplit(" in ", 1)[1].split()[0]) / 1e3
    except (IndexError, ValueError):
        return None


def pct(samples: list[float]) -> str:
    if not samples:
        return "no samples (all dropped)"
    a = np.asarray(samples) * 1e3
    return f"p50 {np.percentile(a, 50):7.2f} ms   p99 {np.percentile(a, 99):7.2f} ms   (n={len(a)})"


class Bench:
    def __init__(self, clients: int) -> None:
        import rclpy
        from geometry_msgs.msg import TwistStamped
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import PointCloud2

        from physdyn_ros.msg import ObjectState, PredictedTrajectory, ShapeFeature
        from physdyn_ros.ros.qos import FEATURE_QOS, LATCHED, STATE_QOS, reliable_client
        from physdyn_ros.srv import PredictTrajectory

        # the client process as lean as a client can be: no parameter services, as many service clients as used
        # (every entity is in the wait set the executor rebuilds on each wake-up)
        self.node = rclpy.create_node("bench", start_parameter_services=False)
        self.cloud = self.node.create_publisher(PointCloud2, "cloud", 2)
        self.state = self.node.create_publisher(ObjectState, "object_state", STATE_QOS)
        self.twist = self.node.create_publisher(TwistStamped, "initial_twist", 10)
        self.events: dict[tuple[str, int], float] = {}
        self.cond = threading.Condition()
        self.node.create_subscription(ShapeFeature, "shape_feature", self._mark("feature"), FEATURE_QOS)
        self.node.create_subscription(PredictedTrajectory, "predicted_trajectory", self._mark("traj"), LATCHED)
        # the documented client QoS (keep-all replies) and, for comparison, rclpy's default service QoS
        self.clients = [reliable_client(self.node, PredictTrajectory, "predict_trajectory")
                        for _ in range(max(1, clients))]
        self.default_clients = [self.node.create_client(PredictTrajectory, "predict_trajectory")
                                for _ in range(max(1, clients))]
        # One spinning thread: the bench measures the node, not its own GIL contention.
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def _mark(self, kind: str):
        from physdyn_ros.ros.convert import time_to_ns

        def cb(msg) -> None:
            with self.cond:
                self.events[(kind, time_to_ns(msg.header.stamp))] = time.perf_counter()
                self.cond.notify_all()
        return cb

    def wait_event(self, kind: str, stamp: int, timeout: float = 30.0) -> float:
        with self.cond:
            if not self.cond.wait_for(lambda: (kind, stamp) in self.events, timeout):
                raise RuntimeError(f"no {kind} stamped {stamp} within {timeout} s")
            return self.events[(kind, stamp)]

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5.0)
        self.executor._work_tracker.wait(5.0)
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default=None, help="checkpoint (default: the shipped model, else random "
                        "weights of config/model_default.yaml)")
    parser.add_argument("--samples", type=int, default=100, help="samples per latency figure")
    parser.add_argument("--clients", type=int, default=8, help="concurrent service clients")
    parser.add_argument("--requests", type=int, default=25, help="requests per concurrent client")
    parser.add_argument("--reply-timeout", type=float, default=30.0, help="s a client waits for one reply before it "
                        "counts it as lost")
    parser.add_argument("--cloud-points", type=int, default=100_000, help="cloud size for the in-process figure")
    parser.add_argument("--dds-cloud-points", type=int, default=20_000,
                        help="cloud size sent over DDS (100k-point clouds, 1.6 MB, were lost on best-effort loopback)")
    parser.add_argument("--domain", type=int, default=None, help="ROS_DOMAIN_ID (default: a random private one)")
    parser.add_argument("--predictor-param", action="append", default=[], metavar="NAME:=VALUE",
                        help="a predictor parameter over config/suite.yaml's (repeatable), e.g. rest_spread:=false")
    args = parser.parse_args()
    for item in args.predictor_param:
        if ":=" not in item:
            parser.error(f"--predictor-param {item!r}: expected NAME:=VALUE")

    os.environ["ROS_DOMAIN_ID"] = str(args.domain if args.domain is not None else np.random.randint(101, 200))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    import rclpy
    from geometry_msgs.msg import TwistStamped
    from std_msgs.msg import Header

    from physdyn_ros.launcher import Suite
    from physdyn_ros.nodes.perception_node import Preprocess, preprocess
    from physdyn_ros.predictor import Predictor
    from physdyn_ros.resources import DEFAULT_MODEL
    from physdyn_ros.ros.cloud import cloud_to_xyz, xyz_to_cloud
    from physdyn_ros.ros.convert import ns_to_time, vector3
    from physdyn_ros.ros.trajectory import object_state
    from physdyn_ros.srv import PredictTrajectory

    tmp = tempfile.TemporaryDirectory(prefix="bench_nodes_")
    if args.model:
        model, note = Path(args.model).resolve(), "given"
    elif DEFAULT_MODEL.is_file():
        model, note = DEFAULT_MODEL, "shipped"
    else:
        model, note = Path(tmp.name) / "random_default.pt", "random weights, default architecture"
        random_weights_checkpoint(model)
    print(f"model: {model} ({note}); ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}; "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")

    rng = np.random.default_rng(0)
    cloud = box_cloud(args.cloud_points, rng)
    dds_cloud = box_cloud(args.dds_cloud_points, rng)
    # in-process reference: what the perception callback does, without DDS
    pred = Predictor.load(model, threads=1)
    msg = xyz_to_cloud(cloud, "world")
    local = []
    for _ in range(max(5, args.samples // 10)):
        t = time.perf_counter()
        pts = cloud_to_xyz(msg, max_points=100_000, rng=rng)
        pred.encode(preprocess(pts, Preprocess()))
        local.append(time.perf_counter() - t)

    overrides = {"perception": [f"model_path:={model}"],
                 "predictor": [f"model_path:={model}", f"horizon:={HORIZON}", "max_feature_age:=0.0",
                               *args.predictor_param]}
    rclpy.init(args=[])  # this process's own arguments are the bench's, not ROS's
    suite = Suite(nodes=["perception", "predictor"], overrides=overrides, log_dir=Path(tmp.name) / "logs")
    bench = None
    try:
        t = time.monotonic()
        suite.start().wait_ready(240)
        print(f"nodes ready in {time.monotonic() - t:.1f} s\n")
        bench = Bench(args.clients)
        time.sleep(1.0)  # discovery

        # perception: cloud -> feature
        percep = []
        for i in range(max(5, args.samples // 5)):
            stamp = T_BASE + i * 10**7
            t = time.perf_counter()
            bench.cloud.publish(xyz_to_cloud(dds_cloud, "world", ns_to_time(stamp)))
            try:
                percep.append(bench.wait_event("feature", stamp, 10.0) - t)
            except RuntimeError:
                pass  # best effort subscription: a dropped cloud is not a latency sample
        print(f"perception, {args.dds_cloud_points // 1000}k-point cloud -> ShapeFeature over DDS: {pct(percep)}"
              f"   dropped {max(5, args.samples // 5) - len(percep)}")
        print(f"perception, {args.cloud_points // 1000}k points, preprocessing + encoding in process: {pct(local)}")

        # twist -> trajectory (the state of the push instant published first, as the sim does)
        lat, twists_lost = [], 0
        for i in range(args.samples):
            stamp = T_BASE + 10**9 + i * 10**7  # within max_feature_age of the feature (stamped near T_BASE)
            s = object_state("world", ns_to_time(stamp), "object", (0.2, 0.1, 0.04), (0, 0, 0, 1), (0, 0, 0), (0, 0, 0))
            bench.state.publish(s)
            tw = TwistStamped(header=Header(frame_id="world", stamp=ns_to_time(stamp)))
            tw.twist.linear, tw.twist.angular = vector3((0.6, 0.1, 0.0)), vector3((0.0, 0.0, 2.0))
            time.sleep(0.005)
            t = time.perf_counter()
            bench.twist.publish(tw)
            try:
                lat.append(bench.wait_event("traj", stamp, 10.0) - t)
            except RuntimeError:
                twists_lost += 1
        print(f"initial_twist -> predicted_trajectory ({HORIZON} steps):  {pct(lat)}   lost {twists_lost}")

        def request() -> PredictTrajectory.Request:
            req = PredictTrajectory.Request(object_id="object", horizon=HORIZON)
            req.header.frame_id = "world"
            req.initial_pose.position.x, req.initial_pose.position.z = 0.2, 0.04
            req.initial_twist.linear, req.initial_twist.angular = vector3((0.6, 0.1, 0)), vector3((0, 0, 2.0))
            return req

        def call(client, req, timeout=30.0):
            # wait on an Event the future sets when the executor thread completes it: a polling loop (sleep 0.2 ms)
            # would wake 5,000 times a second, taking CPU and the GIL from the spinning thread and, on 2 cores, the node
            done = threading.Event()
            fut = client.call_async(req)
            fut.add_done_callback(lambda _: done.set())
            if not done.wait(timeout):
                return None
            return fut.result()

        c0 = bench.clients[0]
        if not c0.wait_for_service(timeout_sec=30):
            raise RuntimeError("predict_trajectory is not available")
        rtt, callback, service_failed, res = [], [], 0, None
        node_pid = next((pr.proc.pid for pr in suite.procs if pr.name == "predictor"), None)
        cpu0 = (process_cpu(node_pid), time.process_time())
        for _ in range(args.samples):
            t = time.perf_counter()
            res = call(c0, request(), timeout=10.0)
            if res is not None and res.success:
                rtt.append(time.perf_counter() - t)
                callback.append(callback_seconds(res.message))
            else:
                service_failed += 1
                print(f"  request failed: {res.message if res is not None else 'no answer within 10 s'}")
        print(f"predict_trajectory round trip ({HORIZON} steps):        {pct(rtt)}   failed {service_failed}")
        node_cpu = process_cpu(node_pid)
        per_request = (lambda a, b: None if a is None or b is None or not rtt else (b - a) / len(rtt))  # noqa: E731
        node_cpu_ms = per_request(cpu0[0], node_cpu)
        bench_cpu_ms = per_request(cpu0[1], time.process_time())
        callback = [c for c in callback if c is not None]
        print(f"  of which the node's callback (its response message):  {pct(callback)}")
        ser, deser = wire_costs(res if res is not None and res.success else None, PredictTrajectory.Response)
        print(f"  the response's CDR serialization (in the node): {pct(ser)}; deserialization (in the client): "
              f"{pct(deser)} (this process, CPU time; the rest is DDS transport and the executors on both sides)")
        if node_cpu_ms is not None and bench_cpu_ms is not None:
            print(f"  CPU per request: the predictor node's process {1e3 * node_cpu_ms:.2f} ms, this client process "
                  f"{1e3 * bench_cpu_ms:.2f} ms (all threads)")

        # concurrency: N clients, each sending requests back to back; with rclpy's default service QoS (keep
        # last 10 replies: every client reads every client's replies, a burst can push its own out) and with the
        # documented one (physdyn_ros.ros.qos.reliable_client)
        n = min(args.clients, len(bench.clients))

        def burst(clients) -> tuple[int, int, float]:
            answered, failed = [0] * n, [0] * n

            def worker(k: int) -> None:
                for _ in range(args.requests):
                    res = call(clients[k], request(), timeout=args.reply_timeout)
                    if res is not None and res.success:
                        answered[k] += 1
                    else:
                        failed[k] += 1

            for c in clients[:n]:
                assert c.wait_for_service(timeout_sec=30)
            threads = [threading.Thread(target=worker, args=(k,)) for k in range(n)]
            t = time.perf_counter()
            for th in threads:
                th.start()
            for th in threads:
                th.join()
            return sum(answered), sum(failed), time.perf_counter() - t

        total = n * args.requests
        default_answered, default_lost, default_wall = burst(bench.default_clients)
        print(f"{n} concurrent clients x {args.requests} requests, rclpy's default service QoS: "
              f"{default_answered / default_wall:6.1f} requests/s, {default_answered}/{total} answered, "
              f"{default_lost} failed or lost")
        good, lost, wall = burst(bench.clients)
        answered, failed = [good], [lost]
        print(f"{n} concurrent clients x {args.requests} requests, the documented QoS (keep-all replies): "
              f"{good / wall:6.1f} requests/s, {good}/{total} answered, {lost} failed or lost")
        print(json.dumps({
            "service_p50_ms": p(rtt, 50), "service_p99_ms": p(rtt, 99), "service_failed": service_failed,
            "service_callback_p50_ms": p(callback, 50), "response_serialize_ms": p(ser, 50),
            "response_deserialize_ms": p(deser, 50),
            "node_cpu_per_request_ms": None if node_cpu_ms is None else round(1e3 * node_cpu_ms, 3),
            "client_cpu_per_request_ms": None if bench_cpu_ms is None else round(1e3 * bench_cpu_ms, 3),
            "twist_to_traj_p50_ms": p(lat, 50), "twist_to_traj_p99_ms": p(lat, 99), "twists_lost": twists_lost,
            f"clients{n}_req_per_s": round(sum(answered) / wall, 1), f"clients{n}_lost": sum(failed),
            f"clients{n}_lost_default_qos": default_lost,
            "perception_dds_p50_ms": p(percep, 50), "perception_dds_dropped": max(5, args.samples // 5) - len(percep),
            "perception_local_p50_ms": p(local, 50), "load_average": round(os.getloadavg()[0], 2)}))
        return 0 if sum(failed) == 0 and service_failed == 0 and twists_lost == 0 else 1
    finally:
        if bench is not None:
            bench.close()
        suite.stop()
        rclpy.try_shutdown()
        tmp.cleanup()


if __name__ == "__main__":
    sys.exit(main())
