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
"""`physdyn predict`: one roll-out of a checkpoint for a cloud file and an initial velocity, printed."""
from __future__ import annotations

import argparse
import json
import math

import numpy as np

from . import geometry as geo
from .predictor import Predictor, load_cloud


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `physdyn predict`."""
    parser.add_argument("--cloud", required=True, help="object points in the table frame: .npy, .ply, .xyz/.txt/.csv")
    parser.add_argument("--lin-vel", nargs=3, type=float, required=True, metavar=("X", "Y", "Z"), help="m/s, world")
    parser.add_argument("--ang-vel", nargs=3, type=float, required=True, metavar=("X", "Y", "Z"), help="rad/s, world")
    parser.add_argument("--horizon", type=int, default=60, help="steps of 1/15 s (default 60 = 4 s)")
    parser.add_argument("--position", nargs=3, type=float, default=None, metavar=("X", "Y", "Z"),
                        help="start COM position (default: the cloud centroid)")
    parser.add_argument("--orientation", nargs=4, type=float, default=None, metavar=("X", "Y", "Z", "W"),
                        help="start orientation quaternion (default: identity)")
    parser.add_argument("--model", default=None, help="checkpoint (default: the shipped model)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--topple-fusion", action="store_true",
                        help="fuse the topple probability with pybullet on the solid the (whole) cloud encloses")
    parser.add_argument("--friction", type=float, default=0.5, help="nominal friction of --topple-fusion's physics")
    parser.add_argument("--json", action="store_true", help="print the whole trajectory as JSON")


def run(args: argparse.Namespace) -> int:
    """Roll out the model for the cloud and velocities of `args`; print the final state (or JSON)."""
    pred = Predictor.load(args.model, device=args.device, threads=1, topple_fusion=args.topple_fusion,
                          friction=args.friction)
    cloud = load_cloud(args.cloud)
    traj = pred.rollout(cloud, args.lin_vel, args.ang_vel, args.horizon, args.position, args.orientation,
                        spread=True)
    spread = traj.spread
    assert spread is not None
    finite = not math.isnan(spread.position)
    if args.json:
        print(json.dumps({"model_id": pred.model_id, "dt": traj.dt, "positions": traj.positions.tolist(),
                          "orientations": traj.orientations.tolist(), "lin_vels": traj.lin_vels.tolist(),
                          "ang_vels": traj.ang_vels.tolist(), "topple_prob": traj.topple_prob.tolist(),
                          "novelty": None if math.isnan(traj.novelty) else traj.novelty,
                          "spread": {"level": spread.level, "position": spread.position if finite else None,
                                     "yaw": spread.yaw if finite else None, "topple": spread.topple}}))
        return 0
    p, q = traj.positions[-1], traj.orientations[-1]
    rot = geo.quat_to_matrix(q)
    yaw = math.degrees(math.atan2(rot[1, 0], rot[0, 0]))  # heading of the object's x axis on the table
    tilt = math.degrees(float(geo.up_tilt_angle(q)))
    moved = np.linalg.norm(p - traj.positions[0])
    print(f"model {pred.model_id}; {len(cloud)} points; {traj.horizon} steps = {traj.horizon * traj.dt:.2f} s")
    print(f"final position    [{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}] m  (moved {moved:.4f} m)")
    print(f"final orientation [{q[0]:.4f}, {q[1]:.4f}, {q[2]:.4f}, {q[3]:.4f}] (x y z w); yaw {yaw:.1f} deg, "
          f"tilt {tilt:.1f} deg")
    print(f"final velocity    [{traj.lin_vels[-1][0]:.4f}, {traj.lin_vels[-1][1]:.4f}, {traj.lin_vels[-1][2]:.4f}] m/s")
    fused = " (fused with physics on the cloud's solid)" if pred.topple_fusion is not None else ""
    print(f"topple probability {traj.topple_probability:.3f}{fused} (spread {spread.topple:.3f})")
    if finite:
        print(f"spread            the object rests within {100 * spread.position:.2f} cm and "
              f"{math.degrees(spread.yaw):.1f} deg of this with probability {spread.level:g} if it stays upright "
              "(calibrated)")
    if not math.isnan(traj.novelty):
        note = "  (beyond 99.5 % of the training inputs: unlike what the model was fitted on)" if traj.novelty > 1 \
            else ""
        print(f"novelty {traj.novelty:.2f}{note}")
    return 0
