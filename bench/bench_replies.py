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
"""Service replies lost under load: N client processes x M predict_trajectory requests, two client QoS.

    .venv/bin/python bench/bench_replies.py [--processes 8] [--requests 100] [--runs 5] [--reply-timeout 10]

Starts the predictor (`physdyn up --nodes predictor`, the shipped model) on a private ROS domain, then, for each
run and each client QoS (rclpy's default service QoS, keep last 10 replies; and physdyn_ros.ros.qos.reliable_client,
keep all), N separate client processes each send M requests back to back (a cloud and a twist: no features needed)
and count the replies that did not arrive within --reply-timeout s. Every client's reply reader receives every
client's replies, so under a burst from several processes a keep-last history can drop a client's own reply.
The last line is one JSON object: lost_default_qos, lost_reliable_qos (summed over runs), requests_per_qos,
req_per_s_reliable (median over runs), processes, requests, runs.
"""
from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CLIENT = r"""
import sys, time, threading
import numpy as np
import rclpy
from physdyn_ros.ros.cloud import xyz_to_cloud
from physdyn_ros.ros.qos import reliable_client
from physdyn_ros.srv import PredictTrajectory

qos, n, timeout = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
rclpy.init()
node = rclpy.create_node(f"reply_bench_{qos}_{sys.argv[4]}", start_parameter_services=False)
client = reliable_client(node, PredictTrajectory, "predict_trajectory") if qos == "reliable" else \
    node.create_client(PredictTrajectory, "predict_trajectory")
if not client.wait_for_service(timeout_sec=60.0):
    print("LOST", n, "ANSWERED", 0, flush=True)
    sys.exit(0)
rng = np.random.default_rng(int(sys.argv[4]))
pts = (rng.uniform(-1, 1, (600, 3)) * (0.05, 0.03, 0.04) + (0.2, 0.1, 0.04)).astype(np.float32)
req = PredictTrajectory.Request()
req.header.frame_id = "world"
req.cloud = xyz_to_cloud(pts, "world")
req.initial_pose.position.x, req.initial_pose.position.y, req.initial_pose.position.z = 0.2, 0.1, 0.04
req.initial_twist.linear.x = 0.4
spin = threading.Thread(target=rclpy.spin, args=(node,), daemon=True)
spin.start()
print("READY", flush=True)
sys.stdin.readline()  # every process starts its burst together
lost = answered = 0
for _ in range(n):
    done = threading.Event()
    future = client.call_async(req)
    future.add_done_callback(lambda _f: done.set())
    if done.wait(timeout) and future.result() is not None and future.result().success:
        answered += 1
    else:
        client.remove_pending_request(future)
        lost += 1
print("LOST", lost, "ANSWERED", answered, flush=True)
import os
os._exit(0)  # the spinning thread is a daemon: no shutdown race at exit
"""


def burst(qos: str, processes: int, requests: int, timeout: float, env: dict) -> tuple[int, float]:
    """(replies lost, requests per second) of one burst of `processes` clients."""
    procs = [subprocess.Popen([sys.executable, "-c", CLIENT, qos, str(requests), str(timeout), str(k)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT)
             for k in range(processes)]
    for p in procs:
        assert p.stdout is not None and p.stdin is not None
        line = p.stdout.readline()
        if not line.startswith("READY"):
            raise SystemExit(f"bench_replies: a client did not start: {line!r}")
    t0 = time.perf_counter()
    for p in procs:
        assert p.stdin is not None
        p.stdin.write("go\n")
        p.stdin.flush()
    lost = answered = 0
    for p in procs:
        out, _ = p.communicate(timeout=requests * timeout + 120)
        words = out.split()
        lost += int(words[words.index("LOST") + 1])
        answered += int(words[words.index("ANSWERED") + 1])
    return lost, answered / (time.perf_counter() - t0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--processes", type=int, default=8)
    ap.add_argument("--requests", type=int, default=100, help="requests per client process")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--reply-timeout", type=float, default=10.0, help="s before a reply counts as lost")
    ap.add_argument("--domain", type=int, default=None, help="ROS_DOMAIN_ID (default: a random private one)")
    args = ap.parse_args()
    from physdyn_ros.launcher import Suite

    domain = args.domain if args.domain is not None else random.SystemRandom().randint(120, 200)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    lost = {"default": 0, "reliable": 0}
    rates: list[float] = []
    with Suite(nodes=["predictor"], env=env, log_dir=Path("/tmp") / f"bench_replies_{domain}") as suite:
        suite.wait_ready(180)
        for run in range(args.runs):
            for qos in ("default", "reliable"):
                n, rate = burst(qos, args.processes, args.requests, args.reply_timeout, env)
                lost[qos] += n
                if qos == "reliable":
                    rates.append(rate)
                print(f"run {run + 1}: {args.processes} processes x {args.requests} requests, {qos} QoS: {n} lost, "
                      f"{rate:.1f} requests/s", flush=True)
    rates.sort()
    print(json.dumps({"lost_default_qos": lost["default"], "lost_reliable_qos": lost["reliable"],
                      "requests_per_qos": args.runs * args.processes * args.requests,
                      "req_per_s_reliable": round(rates[len(rates) // 2], 1), "processes": args.processes,
                      "requests": args.requests, "runs": args.runs}))
    return 0 if lost["reliable"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
