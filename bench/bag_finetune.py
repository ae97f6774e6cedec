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
"""Learning from recorded bags, end to end: does fine-tuning on a recorded session reduce the prediction error?

1. The sim node runs with a friction the model was not trained on (default 0.3; the shipped model saw 0.5) and
   `physdyn record` records it while this script spawns unseen shapes and pushes them through the node's
   services (real DDS, real bag).
2. `physdyn bag2dataset` turns the bag into a dataset; its pushes are split by object into train / val / test.
3. `physdyn evaluate` measures the model on the held-out test pushes, `physdyn train --init` fine-tunes it on
   the train pushes, and the fine-tuned model is evaluated on the same test pushes.

    .venv/bin/python bench/bag_finetune.py --model physdyn_ros/models/default.pt --out runs/bag_finetune

Prints the before / after table (final position / rotation error after 4 s, roll-out errors per step).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
CATEGORIES = ["box", "cylinder", "bottle", "mug", "trashcan", "speaker"]
TOPICS = ["object_state", "cloud", "initial_twist"]


def physdyn(*args: str) -> None:
    run = subprocess.run([PY, "-m", "physdyn_ros.cli", *args], cwd=ROOT, capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"physdyn {args[0]} failed: {run.stderr.strip()[-2000:]}")


def record_session(bag: Path, pushes: int, friction: float, seed: int) -> int:
    import rclpy
    from geometry_msgs.msg import Twist, Vector3

    from physdyn_ros.ros.qos import reliable_client
    from physdyn_ros.srv import PushObject, SpawnObject

    sim = subprocess.Popen([PY, "-m", "physdyn_ros.nodes.sim_node", "--ros-args", "-p", "real_time_factor:=0.0",
                            "-p", "publish_cloud_rate:=5.0", "-p", f"friction:={friction}"],
                           cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rec = subprocess.Popen([PY, "-m", "physdyn_ros.cli", "record", "-o", str(bag), *TOPICS], cwd=ROOT,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           env={**os.environ, "PYTHONUNBUFFERED": "1"})
    rclpy.init()
    node = rclpy.create_node("bag_finetune_driver")
    done = 0
    try:
        while not rec.stdout.readline().startswith("recording "):
            if rec.poll() is not None:
                raise SystemExit(f"recorder exited: {rec.stderr.read()[-1000:]}")
        push, spawn = reliable_client(node, PushObject, "push"), reliable_client(node, SpawnObject, "spawn_object")
        if not (push.wait_for_service(timeout_sec=120) and spawn.wait_for_service(timeout_sec=10)):
            raise SystemExit("the sim node's services did not appear")
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not all(
                any(i.node_name == "recorder" for i in node.get_subscriptions_info_by_topic(f"/{t}")) for t in TOPICS):
            time.sleep(0.1)
        time.sleep(0.5)

        def call(client, request):
            future = client.call_async(request)
            rclpy.spin_until_future_complete(node, future, timeout_sec=30)
            if not (future.done() and future.result().success):
                raise SystemExit(f"service call failed: {future.result()}")
            return future.result()

        rng = np.random.default_rng(seed)
        for i in range(pushes):
            cat = CATEGORIES[i % len(CATEGORIES)]
            yaw = float(rng.uniform(-math.pi, math.pi))
            call(spawn, SpawnObject.Request(category=cat, shape_seed=5000 + i, yaw=yaw,
                                            friction=friction))
            time.sleep(0.45)  # the recorder sees the new object's cloud (5 Hz) before the push
            speed, heading = rng.uniform(0.3, 1.2), rng.uniform(-math.pi, math.pi)
            twist = Twist(linear=Vector3(x=speed * math.cos(heading), y=speed * math.sin(heading), z=0.0),
                          angular=Vector3(x=0.0, y=0.0, z=float(rng.uniform(-4.0, 4.0))))
            call(push, PushObject.Request(use_velocity=True, velocity=twist))
            time.sleep(0.8)  # real_time_factor 0: the push is simulated within milliseconds
            done += 1
            if done % 20 == 0:
                print(f"  {done}/{pushes} pushes", flush=True)
    finally:
        rec.send_signal(signal.SIGINT)
        rec.communicate(timeout=60)
        sim.send_signal(signal.SIGINT)
        try:
            sim.wait(timeout=20)
        except subprocess.TimeoutExpired:
            sim.kill()
        node.destroy_node()
        rclpy.try_shutdown()
    return done


def summary(folder: Path) -> dict:
    m = json.loads((folder / "metrics.json").read_text())["results"]["overall"]["model"]
    return {"pos_med": m["final_pos_cm"]["median"], "pos_p90": m["final_pos_cm"]["p90"],
            "rot_med": m["final_rot_deg"]["median"], "rot_p90": m["final_rot_deg"]["p90"],
            "step_p": m["rollout_step"]["p"], "step_angle": m["rollout_step"]["angle"],
            "n": m["rollout_sequences"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    ap.add_argument("--model", default=str(ROOT / "physdyn_ros" / "models" / "default.pt"))
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "bag_finetune")
    ap.add_argument("--friction", type=float, default=0.3, help="friction of the recorded table (model: 0.5)")
    ap.add_argument("--pushes", type=int, default=150)
    ap.add_argument("--epochs", type=int, default=150, help="fine-tuning epochs")
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    bag, ds = out / "bag", out / "dataset"
    t0 = time.monotonic()
    if not bag.exists():
        print(f"recording {args.pushes} pushes at friction {args.friction} into {bag}", flush=True)
        record_session(bag, args.pushes, args.friction, args.seed)
    t_rec = time.monotonic() - t0
    if not ds.exists():
        physdyn("bag2dataset", str(bag), str(ds), "--friction", str(args.friction), "--test-fraction", "0.3",
                "--val-fraction", "0.15", "--seed", str(args.seed))
    manifest = json.loads((ds / "manifest.json").read_text())
    counts = {k: len(v) for k, v in manifest["splits"].items()}
    print(f"dataset {ds}: pushes per split {counts}", flush=True)
    physdyn("evaluate", "--checkpoint", args.model, "--data", str(ds), "--split", "test", "--baselines",
            "--out", str(out / "eval_before"), "--threads", "2")
    t1 = time.monotonic()
    # one fine-tuning run per starting model: a run folder fine-tuned from another model is never reused
    ft = out / f"finetune_{hashlib.sha256(Path(args.model).read_bytes()).hexdigest()[:12]}"
    if not (ft / "model_best.pt").exists():
        physdyn("train", "--init", args.model, "--data", str(ds), "--out", str(ft), "--max-epochs", str(args.epochs),
                "--set", f"train.lr={args.lr}", "--set", "train.batch_size=32", "--set", "train.val_rollout_horizon=60",
                "--set", "train.select_metric=val_closed_loss", "--threads", "2", "--no-progress")
    t_ft = time.monotonic() - t1
    physdyn("evaluate", "--checkpoint", str(ft / "model_best.pt"), "--data", str(ds), "--split", "test",
            "--baselines", "--out", str(out / "eval_after"), "--threads", "2")
    before, after = summary(out / "eval_before"), summary(out / "eval_after")
    print(f"\nheld-out test pushes of the session (friction {args.friction}, unseen shapes): {before['n']} "
          f"roll-outs without toppling; recording {t_rec:.0f} s, fine-tuning {t_ft:.0f} s ({args.epochs} epochs; "
          "0 s: reused from an earlier run)")
    print("| model | final position cm (median / p90) | final rotation deg (median / p90) | roll-out P cm/step "
          "| roll-out theta deg/step |")
    print("|---|---|---|---|---|")
    for name, s in (("shipped (trained at friction 0.5)", before), ("fine-tuned on the bag", after)):
        print(f"| {name} | {s['pos_med']:.2f} / {s['pos_p90']:.2f} | {s['rot_med']:.2f} / {s['rot_p90']:.2f} | "
              f"{s['step_p']:.3f} | {s['step_angle']:.3f} |")
    (out / "result.json").write_text(json.dumps({"before": before, "after": after, "friction": args.friction,
                                                 "splits": counts}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
