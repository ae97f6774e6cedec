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
"""One whole-push topple probability from the learned model and physics on the whole cloud's solid.

Why: on shapes unlike the training set's, the learned head misses topples that physics catches, and physics on
the cloud's convex hull over-calls them (it weighs the space between a table's legs; shapes.solid). The hull
weighing as the solid the cloud encloses (shapes.solid.solid_hull) gets the mass distribution nearly right, but
neither the friction nor the push exactly; so pybullet runs that body five times (RUNS: the push as given, at 20 %
less and more friction, 10 % slower and faster), and a logistic regression combines what it saw with the model:

    p = sigmoid(a logit(p_model) + sum_k b_k t_k + c)

t_k = 1 where run k tipped the body past the topple angle. The weights are fitted on pushes of new shapes of the
training families (`physdyn fit-topple-fusion`) and stored beside the checkpoint they were fitted for
(`<checkpoint>.topple_fusion.json`, with its model id). They hold for that model and the 4 s whole-push topple.
The runs were chosen by cross-validation over the fitting families (each family predicted by weights fitted on
the others): these five against the first three alone, or with each run's largest tilt.

The solid needs every side of the object (a scan, several cameras, the sim's whole clouds): one camera's view
encloses nothing (shapes.solid). The solid and the five runs cost 25-120 ms a push: the fusion is for single
predictions, not a planner's thousands of candidates (the planner re-simulates its finalists instead:
planning.physics_check).
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

__all__ = ["FusionWeights", "SolidPhysics", "ToppleFusion", "fusion_path", "fit_weights", "FUSION_FRAMES", "RUNS"]

#: Frames (1/15 s) each physics run records: the whole push the weights were fitted for (4 s).
FUSION_FRAMES = 60
#: The physics runs, (friction factor, speed factor) each: the push as given first; a speed factor scales the
#: whole push (its linear and angular velocity: the same contact, a harder or softer impulse).
RUNS: tuple[tuple[float, float], ...] = ((1.0, 1.0), (0.8, 1.0), (1.2, 1.0), (1.0, 0.9), (1.0, 1.1))
#: Probabilities are clipped to [EPS, 1 - EPS] before the logit (the model's 0 and 1 stay finite).
EPS = 1e-4


def fusion_path(checkpoint: Union[str, os.PathLike]) -> Path:
    """Where the fusion weights of a checkpoint live: beside it, `<name>.topple_fusion.json`."""
    path = Path(checkpoint)
    return path.with_name(path.stem + ".topple_fusion.json")


def logit(p: np.ndarray) -> np.ndarray:
    q = np.clip(np.asarray(p, dtype=np.float64), EPS, 1.0 - EPS)
    return np.log(q / (1.0 - q))


@dataclass(frozen=True)
class FusionWeights:
    """The logistic regression's coefficients and what they were fitted for."""

    model_id: str  # the checkpoint's model id: the weights belong to its topple head
    model: float  # on logit(p_model)
    physics: tuple[float, ...]  # on each run's verdict (0 or 1), in the order of `runs`
    bias: float
    runs: tuple[tuple[float, float], ...] = RUNS  # (friction factor, speed factor) of each run
    fitted_on: str = ""  # the dataset(s), for the model card
    pushes: int = 0  # pushes fitted on

    def fuse(self, p_model: Any, toppled: Any) -> np.ndarray:
        """Fused probabilities (B,) of the model's whole-push probabilities (B,) and the runs' verdicts (B, R)."""
        t = np.asarray(toppled, dtype=np.float64).reshape(-1, len(self.runs))
        z = self.model * logit(p_model) + t @ np.asarray(self.physics, dtype=np.float64) + self.bias
        return 1.0 / (1.0 + np.exp(-z))

    def save(self, path: Union[str, os.PathLike]) -> None:
        """Write as JSON, atomically (data.format.atomic_write: the mode open() would give, then a rename)."""
        from .data.format import atomic_write

        text = json.dumps(asdict(self), indent=1) + "\n"
        atomic_write(Path(path), lambda fh: fh.write(text.encode()))

    @classmethod
    def load(cls, path: Union[str, os.PathLike]) -> "FusionWeights":
        """Read a file written by save; ValueError naming the file and the problem."""
        try:
            raw = json.loads(Path(path).read_text())
            raw["physics"] = tuple(raw["physics"])
            raw["runs"] = tuple(tuple(r) for r in raw.get("runs", RUNS))
            weights = cls(**raw)
        except FileNotFoundError:
            raise
        except (OSError, ValueError, TypeError, KeyError) as exc:
            raise ValueError(f"{path}: not topple fusion weights ({type(exc).__name__}: {exc})") from None
        numbers = (weights.model, *weights.physics, weights.bias)
        if not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in numbers):
            raise ValueError(f"{path}: the weights must be finite numbers, got {numbers}")
        if not isinstance(weights.model_id, str) or not isinstance(weights.pushes, int):
            raise ValueError(f"{path}: model_id must be a string and pushes an integer")
        if not weights.runs or len(weights.physics) != len(weights.runs) or not all(
                len(r) == 2 and all(isinstance(f, (int, float)) and 0.0 < f < 10.0 for f in r) for r in weights.runs):
            raise ValueError(f"{path}: one weight per run and runs of two positive factors expected, got "
                             f"{len(weights.physics)} weights for runs {weights.runs}")
        return weights


def fit_weights(p_model: np.ndarray, toppled: np.ndarray, truth: np.ndarray,
                l2: float = 1e-3) -> tuple[np.ndarray, float]:
    """Logistic regression of truth (B,) on [logit(p_model), toppled (B, R)]: (1 + R coefficients, bias). `l2`
    keeps the coefficients finite when a column separates the pushes perfectly."""
    from scipy.optimize import minimize

    x = np.column_stack([logit(p_model), np.asarray(toppled, dtype=np.float64).reshape(len(p_model), -1),
                         np.ones(len(p_model))])
    y = np.asarray(truth, dtype=np.float64) > 0.5
    if len(np.unique(y)) < 2:
        raise ValueError(f"fitting needs pushes that topple and pushes that do not ({int(y.sum())} of {len(y)} "
                         "toppled)")

    def loss(w: np.ndarray) -> tuple[float, np.ndarray]:
        z = x @ w
        p = 1.0 / (1.0 + np.exp(-z))
        value = float(np.mean(np.logaddexp(0.0, z) - y * z) + l2 * np.sum(w[:-1] ** 2))
        grad = x.T @ (p - y) / len(y)
        grad[:-1] += 2.0 * l2 * w[:-1]
        return value, grad

    w = minimize(loss, np.zeros(x.shape[1]), jac=True, method="L-BFGS-B").x
    return w[:-1], float(w[-1])


class SolidPhysics:
    """pybullet runs of a whole cloud's solid hull (pybullet is imported on creation, one DIRECT client)."""

    def __init__(self, friction: float = 0.5, runs: tuple[tuple[float, float], ...] = RUNS,
                 config: Any = None) -> None:
        from .sim import SimConfig, Simulator

        if not 0.0 < friction <= 10.0:
            raise ValueError(f"friction must be in (0, 10], got {friction}")
        self.friction = float(friction)
        self.runs = tuple((float(f), float(v)) for f, v in runs)
        # hull collisions are exact for a lone object on a plane
        self.config = config if config is not None else SimConfig(collision="hull")
        self._sim: Optional[Any] = Simulator(self.config)

    def close(self) -> None:
        if self._sim is not None:
            self._sim.close()
            self._sim = None

    def __enter__(self) -> "SolidPhysics":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def toppled(self, points: np.ndarray, reference: np.ndarray, lin_vel: np.ndarray, ang_vel: np.ndarray,
                frames: int = FUSION_FRAMES, friction: Optional[float] = None) -> np.ndarray:
        """(R,) 1.0 where run k (runs[k]: friction and speed factors) toppled. `points` (N, 3): the whole cloud at
        the pose the push starts from, table frame; `reference` (3,): the point lin_vel refers to (the
        predictor's centre of mass); the body moves rigidly with lin_vel, ang_vel (m/s, rad/s). `friction`: this
        push's nominal coefficient instead of the one given on creation (a dataset's pushes carry their own)."""
        from .shapes.solid import solid_hull
        from .sim import simulate_from_state

        if self._sim is None:
            raise RuntimeError("SolidPhysics is closed")
        shape, com = solid_hull(points)
        w = np.asarray(ang_vel, dtype=np.float64)
        v = np.asarray(lin_vel, dtype=np.float64) + np.cross(w, com - np.asarray(reference, dtype=np.float64))
        mu = self.friction if friction is None else float(friction)
        out = np.zeros(len(self.runs))
        for i, (fm, fs) in enumerate(self.runs):
            rec = simulate_from_state(shape, (1.0, 1.0, 1.0), com, (0.0, 0.0, 0.0, 1.0), v * fs, w * fs,
                                      friction=mu * fm, num_frames=int(frames) + 1, config=self.config, sim=self._sim)
            out[i] = float(np.max(rec["toppled"]))
        return out


class ToppleFusion:
    """Fused whole-push topple probabilities of one checkpoint's model (FusionWeights + SolidPhysics)."""

    def __init__(self, weights: FusionWeights, friction: float = 0.5) -> None:
        self.weights = weights
        self.physics = SolidPhysics(friction, weights.runs)

    @classmethod
    def for_checkpoint(cls, checkpoint: Union[str, os.PathLike], model_id: str,
                       friction: float = 0.5) -> "ToppleFusion":
        """The fusion stored beside `checkpoint`; FileNotFoundError if there is none, ValueError if it was fitted
        for another model."""
        path = fusion_path(checkpoint)
        if not path.is_file():
            raise FileNotFoundError(f"no topple fusion weights for {checkpoint} (expected {path}; fit them with "
                                    "'physdyn fit-topple-fusion')")
        weights = FusionWeights.load(path)
        if weights.model_id != model_id:
            raise ValueError(f"{path} was fitted for model {weights.model_id}, not {model_id}")
        return cls(weights, friction)

    def close(self) -> None:
        self.physics.close()
