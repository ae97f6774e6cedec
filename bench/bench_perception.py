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
"""Perception for a depth camera: speed per cloud, objects found, dense clouds over DDS, a 30 Hz stream.

    .venv/bin/python bench/bench_perception.py [--samples 100] [--duration 30] [--rate 30] [--model PATH]

Clouds are synthetic depth-camera views (physdyn_ros/perception/synthetic.py): a table with three objects seen
from the sim's default camera, in the camera's optical frame, 1 mm depth noise; the node gets the camera pose as
its sensor_frame / sensor_transform parameters (no tf2 here).
* in process: the perception node's own callback work (PerceptionNode.process: read, transform, table plane,
  clusters, outliers, three encodings with the shipped model on one torch thread) on a 100k-point cloud, p50 /
  p99 wall time, and p50 CPU time of this process (what one core spends, whatever else loads the machine);
  objects found and the largest centroid error against the true centroids of the visible points.
* DDS: twenty 100k-point clouds (1.2 MB) from one process to another at 10 Hz, best-effort reader, with the
  shipped Fast DDS profile (config/fastdds.xml) in both, and without it (the control).
* stream: the perception node as its own process (started like `physdyn up --nodes perception`, several-object
  mode), clouds of 20k-100k points published at --rate Hz for --duration s; features per second, clouds that
  gave features per second, latency from publishing a cloud to receiving its last feature, p50 / p99, and the
  p50 over the first and last 5 s (equal: no growing backlog; the node's depth-1 subscription drops the clouds
  it cannot keep up with instead of queueing them).
The last line is one JSON object with these figures.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core: no BLAS / OpenMP helper threads

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SENSOR_FRAME = "camera_optical_frame"
T_BASE = 3_000 * 10**9  # ns, stamps of the stream


def pct(values, q) -> float:
    return float(np.percentile(values, q)) if len(values) else float("nan")


# ------------------------------------------------------------------------------------------------- DDS peer
def peer(mode: str, count: int, arg: float) -> int:
    """One side of the DDS figure, run as its own process (see dense_clouds)."""
    import rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    from physdyn_ros.ros.cloud import xyz_to_cloud

    rclpy.init()
    node = rclpy.create_node(f"bench_dense_{mode}")
    try:
        if mode == "sub":
            got: list[int] = []
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=count, reliability=ReliabilityPolicy.BEST_EFFORT)
            node.create_subscription(PointCloud2, "bench_dense_cloud", lambda m: got.append(m.width), qos)
            print("ready", flush=True)
            deadline = time.monotonic() + arg
            while time.monotonic() < deadline and len(got) < count:
                rclpy.spin_once(node, timeout_sec=0.05)
            print(f"received {len(got)}", flush=True)
        else:
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2, reliability=ReliabilityPolicy.RELIABLE)
            pub = node.create_publisher(PointCloud2, "bench_dense_cloud", qos)
            deadline = time.monotonic() + 30
            while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
            time.sleep(1.0)
            msg = xyz_to_cloud(np.random.default_rng(0).normal(size=(int(arg), 3)).astype(np.float32), "world")
            for _ in range(count):
                pub.publish(msg)
                time.sleep(0.1)
            print(f"sent {count}", flush=True)
            time.sleep(1.0)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def dense_clouds(env: dict[str, str], count: int = 20, points: int = 100_000) -> tuple[int, int]:
    """(sent, received) of `count` clouds between two processes with environment `env`."""
    me = [sys.executable, str(Path(__file__).resolve()), "--peer"]
    sub = subprocess.Popen(me + ["sub", str(count), "60"], env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.DEVNULL, text=True)
    try:
        sub.stdout.readline()
        pub = subprocess.run(me + ["pub", str(count), str(points)], env=env, capture_output=True, text=True,
                             timeout=120)
        out, _ = sub.communicate(timeout=90)
    except subprocess.TimeoutExpired:
        return 0, 0
    finally:
        sub.kill()

    def last_number(text: str) -> int:
        lines = text.strip().splitlines()
        return int(lines[-1].split()[-1]) if lines and lines[-1].split()[-1].isdigit() else 0

    return last_number(pub.stdout), last_number(out)


# ----------------------------------------------------------------------------------------------------- main
def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--samples", type=int, default=100, help="in-process clouds timed")
    parser.add_argument("--duration", type=float, default=30.0, help="s of the stream")
    parser.add_argument("--rate", type=float, default=30.0, help="Hz of the stream")
    parser.add_argument("--model", default=None, help="checkpoint (default: the shipped model)")
    parser.add_argument("--domain", type=int, default=None, help="ROS_DOMAIN_ID (default: random 101-199)")
    parser.add_argument("--peer", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.peer:
        return peer(args.peer[0], int(args.peer[1]), float(args.peer[2]))

    os.environ["ROS_DOMAIN_ID"] = str(args.domain if args.domain is not None else np.random.randint(101, 200))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    from physdyn_ros.suite import DDS_PROFILE_VARS, dds_profile_env

    bare = {k: v for k, v in os.environ.items() if k not in DDS_PROFILE_VARS}
    profile = dds_profile_env(os.environ)  # this process talks to the node: the same profile (unless one is set)
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import PointCloud2

    from physdyn_ros.launcher import Suite
    from physdyn_ros.msg import ShapeFeature
    from physdyn_ros.nodes.perception_node import PerceptionNode
    from physdyn_ros.ros.qos import FEATURE_QOS
    from physdyn_ros.perception.synthetic import DEFAULT_OBJECTS, tabletop_scene
    from physdyn_ros.resources import DEFAULT_MODEL
    from physdyn_ros.ros.cloud import xyz_to_cloud
    from physdyn_ros.ros.convert import ns_to_time, time_to_ns

    model = str(Path(args.model).resolve()) if args.model else str(DEFAULT_MODEL)
    print(f"model: {model}; ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}; DDS profile {profile}; "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    scene = tabletop_scene(100_000, rng=np.random.default_rng(0))
    camera = [Parameter("sensor_frame", value=SENSOR_FRAME),
              Parameter("sensor_transform", value=scene.camera.as_list())]
    result: dict[str, object] = {}

    # 1. in process
    rclpy.init()
    node = PerceptionNode(parameter_overrides=[Parameter("model_path", value=model),
                                               Parameter("single_object", value=False),
                                               Parameter("num_threads", value=1)] + camera)
    msg = xyz_to_cloud(scene.points, SENSOR_FRAME, ns_to_time(10**9))
    for k in range(3):  # warm-up
        node.process(msg)
    wall, cpu = [], []
    feats = []
    for k in range(args.samples):
        msg.header.stamp = ns_to_time(10**9 + (k + 3) * 33_333_333)
        t, c = time.perf_counter(), time.process_time()
        feats, _, reason = node.process(msg)
        wall.append(1e3 * (time.perf_counter() - t))
        cpu.append(1e3 * (time.process_time() - c))
    has_com = node.predictor.estimates_com
    node.destroy_node()
    found = np.array([[f.centroid.x, f.centroid.y, f.centroid.z] for f in feats]).reshape(-1, 3)
    # ShapeFeature.centroid is the roll-out start: the estimated centre of mass for models with a centre-of-mass
    # head (the shipped one), else the visible points' centroid; compare it with what it estimates
    reference = scene.centres if has_com else scene.centroids
    err = [float(np.linalg.norm(found - c, axis=1).min()) if len(found) else float("inf") for c in reference]
    result.update(p50_ms_100k=round(pct(wall, 50), 2), p99_ms_100k=round(pct(wall, 99), 2),
                  cpu_p50_ms_100k=round(pct(cpu, 50), 2), objects_expected=len(scene.objects),
                  objects_found=len(feats), max_centroid_error_cm=round(100 * max(err), 3))
    print(f"in process, 100k points, {len(scene.objects)} objects, camera frame: p50 {pct(wall, 50):.1f} ms, "
          f"p99 {pct(wall, 99):.1f} ms wall; p50 {pct(cpu, 50):.1f} ms CPU; {len(feats)} objects found, "
          f"largest centroid error {100 * max(err):.2f} cm (against the true centres of mass)"
          if has_com else f"largest centroid error {100 * max(err):.2f} cm")

    # 2. DDS, another process
    sent, received = dense_clouds(dict(os.environ))
    sent0, received0 = dense_clouds(bare)
    result.update(dds_100k_sent=sent, dds_100k_received=received, dds_100k_received_without_profile=received0)
    print(f"DDS, 100k-point clouds between two processes: {received} of {sent} with the profile, "
          f"{received0} of {sent0} without")

    # 3. the node as a process, a 30 Hz stream
    tmp = tempfile.TemporaryDirectory(prefix="bench_perception_")
    overrides = {"perception": [f"model_path:={model}", "single_object:=false", f"sensor_frame:={SENSOR_FRAME}",
                                f"sensor_transform:={json.dumps([round(v, 9) for v in scene.camera.as_list()])}"]}
    suite = Suite(nodes=["perception"], overrides=overrides, log_dir=Path(tmp.name) / "logs")
    sizes = [20_000, 40_000, 60_000, 80_000, 100_000]
    clouds = [xyz_to_cloud(tabletop_scene(n, objects=[s.moved(dx=0.01 * k) for s in DEFAULT_OBJECTS],
                                          rng=np.random.default_rng(k)).points, SENSOR_FRAME)
              for k, n in enumerate(sizes)]
    client = rclpy.create_node("bench_perception")
    sent_at: dict[int, float] = {}
    got: dict[int, list[float]] = {}
    lock = threading.Lock()

    def on_feature(f: ShapeFeature) -> None:
        now = time.perf_counter()
        with lock:
            got.setdefault(time_to_ns(f.header.stamp), []).append(now)

    client.create_subscription(ShapeFeature, "shape_feature", on_feature, FEATURE_QOS)
    pub = client.create_publisher(PointCloud2, "cloud", 2)
    executor = SingleThreadedExecutor()
    executor.add_node(client)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    log = Path(tmp.name) / "logs" / "perception.log"
    n, started = int(args.duration * args.rate), False
    try:
        t = time.monotonic()
        try:
            suite.start().wait_ready(240)
            started = True
        except RuntimeError as exc:  # say why; the figures measured so far are still printed
            print(f"\nstream not measured: {exc}\n" + (log.read_text()[-3000:] if log.exists() else ""))
            n = 0
        if started:
            print(f"\nperception node ready in {time.monotonic() - t:.1f} s")
            deadline = time.monotonic() + 20
            while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(1.0)
        start = time.perf_counter()
        for k in range(n):
            due = start + k / args.rate
            time.sleep(max(0.0, due - time.perf_counter()))
            stamp = T_BASE + int(k * 1e9 / args.rate)
            msg = clouds[k % len(clouds)]
            msg.header.stamp = ns_to_time(stamp)
            sent_at[stamp] = time.perf_counter()
            pub.publish(msg)
        time.sleep(2.0 if n else 0.0)  # the last features
    finally:
        stop.set()
        spinner.join(5.0)
        codes = suite.stop()
        executor.shutdown()
        client.destroy_node()
        rclpy.try_shutdown()
        log_tail = log.read_text().splitlines()[-3:] if log.exists() else []
        tmp.cleanup()
    with lock:
        lat = {s: 1e3 * (max(ts) - sent_at[s]) for s, ts in got.items() if s in sent_at}
        n_features = sum(len(ts) for s, ts in got.items() if s in sent_at)
    first = [v for s, v in lat.items() if s < T_BASE + 5 * 10**9]
    last = [v for s, v in lat.items() if s >= T_BASE + int((args.duration - 5) * 1e9)]
    values = list(lat.values())
    result.update(clouds_sent_30hz=n, clouds_with_features_30hz=len(lat),
                  clouds_per_s_30hz=round(len(lat) / args.duration, 2),
                  features_per_s_30hz=round(n_features / args.duration, 2),
                  latency_p50_ms_30hz=round(pct(values, 50), 1), latency_p99_ms_30hz=round(pct(values, 99), 1),
                  latency_p50_first_5s_ms=round(pct(first, 50), 1), latency_p50_last_5s_ms=round(pct(last, 50), 1))
    print(f"stream, {args.rate:g} Hz for {args.duration:g} s of {sizes[0] // 1000}k-{sizes[-1] // 1000}k-point "
          f"clouds: {len(lat)} of {n} clouds gave features ({len(lat) / args.duration:.1f} per s), "
          f"{n_features / args.duration:.1f} features per s; latency p50 {pct(values, 50):.1f} ms, p99 "
          f"{pct(values, 99):.1f} ms; p50 first 5 s {pct(first, 50):.1f} ms, last 5 s {pct(last, 50):.1f} ms "
          f"(node exit {codes.get('perception')})")
    if log_tail:
        print("  node log ends: " + " | ".join(log_tail))
    result.update(load_average=round(os.getloadavg()[0], 2), cpus=os.cpu_count())
    print(json.dumps({k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in result.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
