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
"""What the topple fusion costs a prediction: `Predictor.rollout` with and without `topple_fusion`, side by side.

    .venv/bin/python bench/bench_fusion.py [--repeats 20] [--points 3000]

Three whole clouds (`--points` surface samples, resting on the table): a box 8 x 6 x 12 cm, an upright cylinder
r 4 cm h 20 cm, a ball r 5 cm; random pushes 0.2-1.0 m/s along x with a spin of up to 3 rad/s about z. Each
roll-out is 60 steps on one torch thread. Prints per shape the p50 / p90 of the model alone and fused, and the
time the solid takes to build (shapes.solid.solid_hull); the last line is one JSON object {shape: {model_p50_ms,
model_p90_ms, fused_p50_ms, fused_p90_ms, solid_ms}, "cpu": model name}.
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main() -> int:
    import trimesh

    from physdyn_ros.predictor import Predictor
    from physdyn_ros.shapes.solid import solid_hull

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--points", type=int, default=3000)
    args = ap.parse_args()
    plain, fused = Predictor.load(threads=1), Predictor.load(threads=1, topple_fusion=True)
    shapes = {"box 8x6x12 cm": trimesh.creation.box(extents=(0.08, 0.06, 0.12)),
              "cylinder r4 h20 cm": trimesh.creation.cylinder(radius=0.04, height=0.2),
              "ball r5 cm": trimesh.creation.icosphere(radius=0.05)}
    rng = np.random.default_rng(0)
    result: dict = {}
    for name, mesh in shapes.items():
        pts = np.asarray(trimesh.sample.sample_surface(mesh, args.points, seed=0)[0])
        pts[:, 2] -= pts[:, 2].min()
        pushes = [((rng.uniform(0.2, 1.0), 0.0, 0.0), (0.0, 0.0, rng.uniform(-3.0, 3.0))) for _ in range(args.repeats)]
        row = {}
        for label, pred in (("model", plain), ("fused", fused)):
            code = pred.encode(pts)
            times = []
            for v, w in pushes:
                t = time.perf_counter()
                pred.rollout(code, v, w, 60)
                times.append(1e3 * (time.perf_counter() - t))
            row[f"{label}_p50_ms"] = round(float(np.median(times)), 2)
            row[f"{label}_p90_ms"] = round(float(np.percentile(times, 90)), 2)
        t = time.perf_counter()
        for _ in range(5):
            solid_hull(pts)
        row["solid_ms"] = round(1e3 * (time.perf_counter() - t) / 5, 2)
        result[name] = row
        print(f"{name:<20} model p50 {row['model_p50_ms']:6.2f} ms (p90 {row['model_p90_ms']:.2f})   fused p50 "
              f"{row['fused_p50_ms']:6.1f} ms (p90 {row['fused_p90_ms']:.1f})   the solid {row['solid_ms']:.1f} ms",
              flush=True)
    fused.close()
    result["cpu"] = cpu_name()
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
