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
"""Online adaptation: re-predict a push as its observed states arrive (the paper's "steps in").

The learned model infers what it cannot see in a cloud (friction, mass distribution) from motion: feeding the
observed states of frames 1..K instead of its own predictions conditions the LSTM's memory on the real motion,
and the free-running rest of the roll-out follows the real object better (paper, friction experiment).

    adapter = OnlineAdapter(predictor, code, lin_vel, ang_vel, position=p0, orientation=q0, horizon=60)
    adapter.open_loop                                  # the prediction made at the push
    traj = adapter.observe(pos, quat, lin_vel, ang_vel)   # frame 1 arrived: re-predicted trajectory
    traj = adapter.observe(...)                           # frame 2 ... (up to max_steps_in)

Observed states must be consecutive frames DT apart after the push (frame 1, 2, ...), in the table frame;
position and orientation of the start must be given in the same frame as the observations (the tracker's),
since the model's rotation increments are computed between consecutive orientations.
"""
from __future__ import annotations

from typing import Any, Optional, Sequence

import numpy as np

from ..predictor import Observed, Trajectory


def repredict(predictor: Any, shape: Any, lin_vel: Any, ang_vel: Any, positions: Sequence[Any],
              orientations: Sequence[Any], lin_vels: Sequence[Any], ang_vels: Sequence[Any], horizon: int = 60,
              position: Any = None, orientation: Any = None) -> Trajectory:
    """One re-prediction with K observed states (frames 1..K, arrays (K, 3) / (K, 4)); K = 0 is open loop.

    Raises ValueError (from the Predictor) for malformed or non-finite states or K >= horizon.
    """
    k = len(positions)
    if not (len(orientations) == len(lin_vels) == len(ang_vels) == k):
        raise ValueError(f"observed arrays disagree in length: {k} positions, {len(orientations)} orientations, "
                         f"{len(lin_vels)} lin_vels, {len(ang_vels)} ang_vels")
    observed = None
    if k:
        observed = Observed(positions=np.asarray(positions, dtype=np.float64).reshape(k, 3),
                            orientations=np.asarray(orientations, dtype=np.float64).reshape(k, 4),
                            lin_vels=np.asarray(lin_vels, dtype=np.float64).reshape(k, 3),
                            ang_vels=np.asarray(ang_vels, dtype=np.float64).reshape(k, 3))
    return predictor.rollout(shape, lin_vel, ang_vel, horizon=horizon, position=position, orientation=orientation,
                             observed=observed)


class OnlineAdapter:
    """The prediction of one push, re-made each time an observed state arrives (see the module docstring).

    max_steps_in caps the observed states fed to the model (later observations are kept but not used, so the
    cost per update stays one roll-out); None = up to horizon - 1.
    """

    def __init__(self, predictor: Any, shape: Any, lin_vel: Any, ang_vel: Any, position: Any = None,
                 orientation: Any = None, horizon: int = 60, max_steps_in: Optional[int] = None) -> None:
        self.predictor = predictor
        self.shape = predictor.encode(shape) if isinstance(shape, np.ndarray) else shape
        self.lin_vel = np.asarray(lin_vel, dtype=np.float64)
        self.ang_vel = np.asarray(ang_vel, dtype=np.float64)
        self.position = position
        self.orientation = orientation
        self.horizon = int(horizon)
        limit = self.horizon - 1 if max_steps_in is None else int(max_steps_in)
        if not 0 <= limit < self.horizon:
            raise ValueError(f"max_steps_in must be in 0..{self.horizon - 1}, got {max_steps_in}")
        self.max_steps_in = limit
        self._obs: dict[str, list[np.ndarray]] = {"positions": [], "orientations": [], "lin_vels": [], "ang_vels": []}
        self.open_loop: Trajectory = predictor.rollout(self.shape, self.lin_vel, self.ang_vel, horizon=self.horizon,
                                                       position=position, orientation=orientation)
        self.prediction: Trajectory = self.open_loop

    @property
    def observed_steps(self) -> int:
        """Observed states received so far."""
        return len(self._obs["positions"])

    @property
    def steps_in(self) -> int:
        """Observed states the current prediction used."""
        return min(self.observed_steps, self.max_steps_in)

    def observe(self, position: Any, orientation: Any, lin_vel: Any, ang_vel: Any) -> Trajectory:
        """Add the next observed frame and return the re-predicted trajectory (frame 0 = the push)."""
        state = {"positions": (position, 3), "orientations": (orientation, 4), "lin_vels": (lin_vel, 3),
                 "ang_vels": (ang_vel, 3)}
        arrays = {}
        for key, (value, size) in state.items():
            a = np.asarray(value, dtype=np.float64).reshape(-1)
            if a.shape != (size,) or not np.all(np.isfinite(a)):
                raise ValueError(f"observed {key[:-1]} must be {size} finite numbers, got {value!r}")
            arrays[key] = a
        for key, a in arrays.items():
            self._obs[key].append(a)
        k = self.steps_in
        if self.observed_steps <= self.max_steps_in:  # beyond max_steps_in the prediction no longer changes
            obs = self._obs
            self.prediction = repredict(self.predictor, self.shape, self.lin_vel, self.ang_vel,
                                        obs["positions"][:k], obs["orientations"][:k], obs["lin_vels"][:k],
                                        obs["ang_vels"][:k], horizon=self.horizon, position=self.position,
                                        orientation=self.orientation)
        return self.prediction
