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
"""`physdyn fit-spread`: calibrate a checkpoint's rest-pose spread (physdyn_ros.spread) on a dataset.

    physdyn fit-spread --data data/fit_families [--checkpoint CKPT] [--splits train val test]
        [--max-sequences 1500] [--out PATH]

For each push (evenly spaced over the splits), the Predictor's roll-out with its spread from the whole cloud at
the true start pose and the true initial velocities (60 steps = 4 s), against the simulated rest pose. The
upright pushes' errors over their sensitivities give the split-conformal factors. Fit on shapes the spread is
not measured on (the model card's run: new shapes of the trained families; bench/spread_reliability.py measures
the coverage on held-out families). Writes `<checkpoint>.spread.json` beside the checkpoint, atomically, unless
--out says otherwise.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from .fit_args import add_fit_arguments, fit_pushes
from .geometry import yaw_of
from .spread import LEVELS, SpreadCalibration, fit_calibration, spread_path

__all__ = ["HORIZON", "measure", "add_arguments", "run"]

HORIZON = 60  # steps: the rest pose `physdyn evaluate` scores


def measure(predictor: Any, sims: Any, index: np.ndarray, horizon: int = HORIZON, observed: int = 0
            ) -> dict[str, np.ndarray]:
    """Per push `index` of a dataset: the prediction's spread and its true errors; `observed` true states after
    the push (frames 1..observed) fed first, as a refinement does.

    Returns arrays: sensitivity (n, 2) m / rad; error (n, 2) rest position (x-y) and yaw errors, m / rad;
    radius (n, 2) the calibrated radii at the default level (NaN without a calibration); topple_probability,
    topple_spread (n,); toppled (n,) bool, whether the push toppled within the horizon.
    """
    from scipy.spatial.transform import Rotation

    from .geometry import quat_rotate

    if sims.num_frames <= horizon:
        raise ValueError(f"the dataset's {sims.num_frames} frames do not reach the {horizon}-step rest pose")
    out: dict[str, list[Any]] = {k: [] for k in ("sensitivity", "error", "radius", "topple_probability",
                                                 "topple_spread", "toppled")}
    for i in index:
        pts = sims.points[sims.shape_index[i]].astype(np.float64) * sims.scale[i].astype(np.float64)
        q0 = sims.quat[i, 0].astype(np.float64)
        p0 = sims.pos[i, 0].astype(np.float64)
        cloud = quat_rotate(np.broadcast_to(q0, pts.shape[:1] + (4,)), pts) + p0
        seen = None
        if observed:  # the true states, their orientations relative to the start (the cloud's own pose)
            rel = Rotation.from_quat(sims.quat[i, 1:observed + 1]) * Rotation.from_quat(q0).inv()
            seen = {"positions": sims.pos[i, 1:observed + 1], "orientations": rel.as_quat(),
                    "lin_vels": sims.lin_vel[i, 1:observed + 1], "ang_vels": sims.ang_vel[i, 1:observed + 1]}
        traj = predictor.rollout(predictor.encode(cloud), sims.lin_vel[i, 0], sims.ang_vel[i, 0], horizon,
                                 position=p0, observed=seen, spread=True)
        turn = Rotation.from_quat(sims.quat[i, horizon]) * Rotation.from_quat(q0).inv()  # the true yaw change
        yaw_error = np.angle(np.exp(1j * (yaw_of(traj.orientations[-1]) - yaw_of(turn.as_quat()))))
        out["sensitivity"].append(traj.spread.sensitivity)
        out["error"].append((np.linalg.norm(traj.positions[-1, :2] - sims.pos[i, horizon, :2]), abs(yaw_error)))
        out["radius"].append((traj.spread.position, traj.spread.yaw))
        out["topple_probability"].append(traj.topple_probability)
        out["topple_spread"].append(traj.spread.topple)
        out["toppled"].append(bool(sims.toppled[i, :horizon + 1].any()))
    return {k: np.asarray(v, dtype=bool if k == "toppled" else np.float64) for k, v in out.items()}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_fit_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from .predictor import Predictor

    ckpt, sims, index = fit_pushes(args, 20)
    predictor = Predictor.load(ckpt, threads=1)
    m = measure(predictor, sims, index)
    upright = ~m["toppled"]
    pos, yaw = fit_calibration(m["sensitivity"][upright], m["error"][upright])
    cal = SpreadCalibration(model_id=predictor.model_id, levels=LEVELS, position_factors=pos, yaw_factors=yaw,
                            fitted_on=f"{Path(args.data).name} ({', '.join(args.splits)})",
                            pushes=int(upright.sum()))
    out = args.out or spread_path(ckpt)
    cal.save(out)
    print(f"{len(index)} pushes, {int(upright.sum())} upright: factors position {np.round(pos, 2).tolist()}, yaw "
          f"{np.round(yaw, 2).tolist()} at levels {list(LEVELS)} -> {out}")
    return 0
