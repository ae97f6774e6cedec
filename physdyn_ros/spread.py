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
"""The spread of a prediction: how far the true rest pose may lie from the predicted one.

The model is deterministic; its errors grow where the outcome is sensitive to the push (an object that slides
far, rolls, or sits on the edge of turning one way or the other). The push is rolled out again a little weaker
and stronger (SPEEDS: the impulse, so both velocities, x0.9 and x1.1): the RMS change of the rest position and
yaw is the push's sensitivity (the velocities of observed states fed first are scaled alike: the model takes
the push over at the last of them). A calibration (SpreadCalibration, fitted by
`physdyn fit-spread` on shapes the model was not trained on, stored beside the checkpoint) turns it into radii
that held the true rest position and yaw of upright pushes with a stated probability (split-conformal quantiles
of error / sensitivity: no assumption on the errors' distribution; a coverage over pushes like the fitted ones,
from their true initial velocities, at the 60-step rest pose). The topple spread is the standard deviation
of the whole-push topple probability over the push and its perturbations. The model card's reliability table
gives the measured coverage on held-out families (bench/spread_reliability.py).
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

__all__ = ["SPEEDS", "LEVELS", "RestSpread", "SpreadCalibration", "spread_path", "perturbed_twists",
           "sensitivity", "fit_calibration"]

#: factors on the push's velocities (its impulse) of the perturbed pushes
SPEEDS: tuple[float, ...] = (0.9, 1.1)
#: coverage levels a calibration stores radii for; messages carry DEFAULT_LEVEL's
LEVELS: tuple[float, ...] = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95)
DEFAULT_LEVEL = 0.9
#: smallest sensitivities the calibration scales (m, rad): a push that barely moves still has the model's error
FLOORS = (0.002, 0.02)


@dataclass(frozen=True)
class RestSpread:
    """A prediction's spread: radii that hold the true rest pose with probability `level` (upright pushes; NaN
    without a calibration)."""

    level: float
    position: float  # m, around the predicted rest position (x-y)
    yaw: float  # rad, around the predicted rest yaw
    topple: float  # standard deviation of the whole-push topple probability over the push and its perturbations
    sensitivity: tuple[float, float]  # (m, rad) RMS change of the rest position and yaw under SPEEDS


def spread_path(checkpoint: Union[str, os.PathLike]) -> Path:
    """Where a checkpoint's spread calibration lives: beside it, `<name>.spread.json`."""
    path = Path(checkpoint)
    return path.with_name(path.stem + ".spread.json")


def perturbed_twists(lin_vel: np.ndarray, ang_vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) linear and angular velocities of the perturbed pushes of (3,) lin_vel, ang_vel: each SPEEDS
    factor scales both (a weaker or stronger impulse at the same contact)."""
    k = np.asarray(SPEEDS, dtype=np.float64)[:, None]
    return k * np.asarray(lin_vel, dtype=np.float64), k * np.asarray(ang_vel, dtype=np.float64)


def sensitivity(rest_xy: np.ndarray, rest_yaw: float, perturbed_xy: np.ndarray,
                perturbed_yaw: np.ndarray) -> tuple[float, float]:
    """(m, rad) RMS distance of the perturbed rest positions (P, 2) and yaws (P,) from the push's own."""
    d = np.asarray(perturbed_xy, dtype=np.float64) - np.asarray(rest_xy, dtype=np.float64)
    turn = np.angle(np.exp(1j * (np.asarray(perturbed_yaw, dtype=np.float64) - rest_yaw)))
    return float(np.sqrt(np.mean(np.sum(d * d, axis=-1)))), float(np.sqrt(np.mean(turn * turn)))


@dataclass(frozen=True)
class SpreadCalibration:
    """Per level, the factor on the (floored) sensitivity that gives the radius; what it was fitted for."""

    model_id: str  # the checkpoint's model id: the factors belong to its dynamics
    levels: tuple[float, ...] = LEVELS
    position_factors: tuple[float, ...] = ()
    yaw_factors: tuple[float, ...] = ()
    floors: tuple[float, float] = FLOORS
    fitted_on: str = ""
    pushes: int = 0  # upright pushes fitted on

    def radii(self, sens: tuple[float, float], level: float = DEFAULT_LEVEL) -> tuple[float, float]:
        """(m, rad) the position and yaw radii at `level` (one of `levels`) for a push of sensitivity `sens`."""
        if level not in self.levels:
            raise ValueError(f"level {level} not calibrated (levels: {list(self.levels)})")
        i = self.levels.index(level)
        return (self.position_factors[i] * max(sens[0], self.floors[0]),
                self.yaw_factors[i] * max(sens[1], self.floors[1]))

    def within_level(self, sens: tuple[float, float], position_margin: float,
                     yaw_margin: Optional[float] = None) -> float:
        """A lower bound on the chance that the true rest pose lies within a tolerance, from the margins (m, rad:
        the tolerance less the predicted error; None ignores the yaw): the highest level whose position radius
        fits the margin (the triangle inequality), and with the yaw L_pos + L_yaw - 1 (the union bound); 0.0
        where none fits."""
        fits = [max([lv for lv in self.levels if self.radii(sens, lv)[j] <= margin], default=0.0)
                for j, margin in enumerate((position_margin, yaw_margin)) if margin is not None]
        return max(0.0, sum(fits) - (len(fits) - 1))

    def save(self, path: Union[str, os.PathLike]) -> None:
        """Write as JSON, atomically."""
        from .data.format import atomic_write

        text = json.dumps(asdict(self), indent=1) + "\n"
        atomic_write(Path(path), lambda fh: fh.write(text.encode()))

    @classmethod
    def load(cls, path: Union[str, os.PathLike]) -> "SpreadCalibration":
        """Read a file written by save; FileNotFoundError if there is none, ValueError naming the file and the
        problem otherwise."""
        try:
            raw = json.loads(Path(path).read_text())
            for key in ("levels", "position_factors", "yaw_factors", "floors"):
                raw[key] = tuple(float(x) for x in raw[key])
            cal = cls(**raw)
        except FileNotFoundError:
            raise
        except (OSError, ValueError, TypeError, KeyError) as exc:
            raise ValueError(f"{path}: not a spread calibration ({type(exc).__name__}: {exc})") from None
        numbers = (*cal.levels, *cal.position_factors, *cal.yaw_factors, *cal.floors)
        if not (len(cal.levels) == len(cal.position_factors) == len(cal.yaw_factors) > 0 and len(cal.floors) == 2
                and all(math.isfinite(x) and x > 0 for x in numbers) and all(0 < x < 1 for x in cal.levels)):
            raise ValueError(f"{path}: one positive finite factor per level in (0, 1) and two positive floors "
                             f"expected, got levels {cal.levels}, factors {cal.position_factors} / "
                             f"{cal.yaw_factors}, floors {cal.floors}")
        if not isinstance(cal.model_id, str) or not isinstance(cal.pushes, int):
            raise ValueError(f"{path}: model_id must be a string and pushes an integer")
        return cal


def fit_calibration(sens: np.ndarray, errors: np.ndarray, levels: Sequence[float] = LEVELS,
                    floors: tuple[float, float] = FLOORS) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Split-conformal factors: per level, the ceil((n + 1) level)-th smallest error / floored sensitivity.

    Args:
        sens: (n, 2) sensitivities (m, rad) of upright pushes.
        errors: (n, 2) their rest position and yaw errors (m, rad).

    Returns:
        The position and yaw factors, one per level.
    """
    sens, errors = np.asarray(sens, dtype=np.float64), np.asarray(errors, dtype=np.float64)
    if sens.shape != errors.shape or sens.ndim != 2 or sens.shape[1] != 2:
        raise ValueError(f"sens and errors must both be (n, 2), got {sens.shape} and {errors.shape}")
    n = len(sens)
    if n < 20 or not np.all(np.isfinite(sens)) or not np.all(np.isfinite(errors)):
        raise ValueError(f"fitting needs at least 20 pushes of finite figures, got {n}")
    out = []
    for j in range(2):
        ratio = np.sort(errors[:, j] / np.maximum(sens[:, j], floors[j]))
        out.append(tuple(float(ratio[min(n - 1, math.ceil((n + 1) * lv) - 1)]) for lv in levels))
    return out[0], out[1]
