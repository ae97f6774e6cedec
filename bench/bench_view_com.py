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
"""Centre of mass from one camera's view: how far a new track's estimate lies from the truth, per shape family.

    .venv/bin/python bench/bench_view_com.py [--seeds 9305,9306,9307] [--yaws 3] [--depth-noise 0.002]
        [--flying-pixels 0.02] [--categories box,bottle,...]

Each shape of every procedural category (the paper's six and the families, docs/architecture.md; seeds no model
was trained on) is spawned alone at random yaws and places on the sim's table, settles, and is rendered by the
sim's 320 x 240 depth camera from its default eye (what bench_tracking.py feeds the perception node); its points
5 mm above the table are the view. Three estimates of the centre of mass against the simulator's:
* footprint: `pose_tracking.footprint_com`, what the perception node takes for a new track (`track_com:
  footprint`, the default);
* outline: the same without the axis of a surface of revolution (`pose_tracking.top_outline_xy`, else
  `column_com`): the reference;
* column: `pose_tracking.column_com`, the solid under the view's surface alone;
* head: the shipped encoder's centre-of-mass head (`track_com: model`).
With --depth-noise / --flying-pixels the views first get a depth camera's errors (bench_tracking.sensor_noise).
Printed: the x-y error (mm) per category and over all views, median / p90; the last line one JSON object.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

EYE, TARGET = (0.6, 0.0, 0.45), (0.0, 0.0, 0.05)  # the sim node's default camera
ESTIMATES = ("footprint", "outline", "column", "head")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="9305,9306,9307", help="shape seeds per category, comma-separated")
    ap.add_argument("--yaws", type=int, default=3, help="random poses per shape")
    ap.add_argument("--categories", default="", help="comma-separated (default: every procedural category)")
    ap.add_argument("--depth-noise", type=float, default=0.0, help="m of depth noise at 1 m (grows with range^2)")
    ap.add_argument("--flying-pixels", type=float, default=0.0, help="share of points moved 1-6 cm behind")
    ap.add_argument("--seed", type=int, default=0, help="poses and noise")
    args = ap.parse_args()
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s]
    except ValueError:
        ap.error(f"--seeds must be comma-separated integers, got {args.seeds!r}")
    if not seeds or args.yaws < 1 or args.depth_noise < 0 or not 0 <= args.flying_pixels < 1:
        ap.error("need at least one seed, --yaws >= 1, --depth-noise >= 0 and --flying-pixels in [0, 1)")

    import torch

    from bench_tracking import sensor_noise
    from physdyn_ros.perception.pose_tracking import column_com, footprint_com, top_outline_xy
    from physdyn_ros.predictor import Predictor
    from physdyn_ros.shapes import ALL_CATEGORIES, PYBULLET_DATA_CATEGORY, resolve_shape
    from physdyn_ros.sim import SimConfig, Simulator
    from physdyn_ros.sim.camera import CameraSpec, DepthCamera

    categories = [c for c in args.categories.split(",") if c] or [c for c in ALL_CATEGORIES
                                                                  if c != PYBULLET_DATA_CATEGORY]
    unknown = sorted(set(categories) - set(ALL_CATEGORIES))
    if unknown:
        ap.error(f"unknown categories {unknown} (known: {list(ALL_CATEGORIES)})")
    torch.set_num_threads(1)
    predictor = Predictor.load(threads=1)
    spec = CameraSpec.make(EYE, TARGET, (320, 240), 60.0)
    rng = np.random.default_rng(args.seed)
    noise_rng = np.random.default_rng([args.seed, 1])
    errors: dict[str, dict[str, list[float]]] = {c: {e: [] for e in ESTIMATES} for c in categories}
    for category in categories:
        for seed in seeds:
            shape = resolve_shape(category, seed)
            for _ in range(args.yaws):
                yaw = float(rng.uniform(-math.pi, math.pi))
                xy = rng.uniform([-0.2, -0.2], [0.1, 0.2])
                with Simulator(SimConfig(friction=0.5, collision="hull")) as sim:
                    sim.spawn(shape, xy=(float(xy[0]), float(xy[1])), yaw=yaw, object_id="o")
                    for _ in range(15):  # settle
                        sim.step()
                    truth = np.asarray(sim.states()["o"][0], dtype=np.float64)
                    points = DepthCamera(sim).render(spec)
                if args.depth_noise > 0 or args.flying_pixels > 0:
                    points = sensor_noise(points, spec.eye, noise_rng, args.depth_noise, args.flying_pixels)
                view = points[points[:, 2] > 0.005]
                if len(view) < 50:
                    continue
                top, column = top_outline_xy(view), column_com(view)
                found = {"footprint": footprint_com(view), "column": column,
                         "outline": column if top is None else top,
                         "head": np.asarray(predictor.encode(view).centroid)}
                for name, com in found.items():
                    errors[category][name].append(1e3 * float(np.linalg.norm(com[:2] - truth[:2])))
    predictor.close()

    def stats(values: list[float]) -> tuple[float | None, float | None]:
        if not values:
            return None, None
        return round(float(np.median(values)), 2), round(float(np.percentile(values, 90)), 2)

    print(f"x-y error of the centre of mass from one camera's view, mm (median / p90); seeds {seeds}, "
          f"{args.yaws} poses each, depth noise {args.depth_noise} m, flying pixels {args.flying_pixels}")
    print(f"{'category':16s}" + "".join(f"{e:>18s}" for e in ESTIMATES))
    for category in categories:
        cells = [stats(errors[category][e]) for e in ESTIMATES]
        print(f"{category:16s}" + "".join(f"{str(m):>10s} / {str(p):<5s}" for m, p in cells))
    result: dict[str, object] = {"views": sum(len(errors[c]["footprint"]) for c in categories)}
    for e in ESTIMATES:
        median, p90 = stats([v for c in categories for v in errors[c][e]])
        result[f"{e}_xy_error_median_mm"], result[f"{e}_xy_error_p90_mm"] = median, p90
        print(f"{'all':16s}{e:>10s}: {median} / {p90} mm")
    foot, outline = result["footprint_xy_error_median_mm"], result["outline_xy_error_median_mm"]
    result["footprint_over_outline_median"] = (round(float(foot) / float(outline), 3)  # type: ignore[arg-type]
                                               if foot is not None and outline else None)
    result.update({"depth_noise_m": args.depth_noise, "flying_pixels": args.flying_pixels, "seeds": seeds,
                   "yaws": args.yaws})
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
