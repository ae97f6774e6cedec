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
"""What the predictor node holds between messages: twists waiting for the state of their push instant, and
predictions waiting for the observed states that refine them; `refine` re-runs the latter as their states
arrive."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from .convert import ns_to_time, time_to_ns
from .trajectory import trajectory_to_msg


@dataclass
class ParkedTwist:
    """A twist waiting (at most state_wait) for the object_state stamped at its push instant."""

    msg: Any  # geometry_msgs/TwistStamped
    t_start: float  # time.monotonic() when the twist arrived
    deadline: float


@dataclass
class PendingRefinement:
    """A prediction waiting for `steps_in` observed states before it is re-run with them."""

    object_id: str
    t0_ns: int
    position: np.ndarray
    orientation: np.ndarray
    lin_vel: np.ndarray
    ang_vel: np.ndarray
    feature: Any  # physdyn_ros/ShapeFeature the prediction was made with
    deadline: float  # time.monotonic() after which the refinement is dropped
    published: int = 0  # observed states used by the last re-prediction published


def states_after(states: Any, t0_ns: int, dt_ns: int, k: int) -> list:
    """The first k of `states` (ObjectStates in stamp order) stamped at least half a step after t0_ns: the
    observed frames 1..k of a push at t0_ns."""
    return [s for s in states if t0_ns + dt_ns // 2 <= time_to_ns(s.header.stamp)][:k]


def refine(node: Any) -> None:
    """Re-predict the node's pending pushes (PredictorNode._pending) as observed states arrive: one corrected
    trajectory per new observed state, fed as "steps in", until `steps_in` states have been used; a push whose
    states stop coming is dropped with the reason once its deadline passes."""
    steps_in = int(node._param("steps_in"))
    dt_ns = int(round(float(node.predictor.dt) * 1e9))
    keep = []
    for p in node._pending:
        with node._lock:
            obs = states_after(node._observed.get(p.object_id, ()), p.t0_ns, dt_ns, steps_in)
        if len(obs) <= p.published:
            if time.monotonic() < p.deadline:
                keep.append(p)
            else:
                node._fail(f"steps_in {steps_in}: only {len(obs)} observed states of '{p.object_id}' after the "
                           "push; refinement stopped")
            continue
        try:
            observed = node.observed(obs, p)
            traj = node.predictor.rollout(node.shape_code(p.feature), p.lin_vel, p.ang_vel, horizon=node.horizon(),
                                          position=p.position, orientation=p.orientation, observed=observed,
                                          spread=bool(node._param("rest_spread")))
        except Exception as exc:  # noqa: BLE001 - one bad refinement must not stop the others
            node._fail(f"refinement with {len(obs)} observed states failed: {exc}")
            continue
        out = trajectory_to_msg(traj, node.table_frame, ns_to_time(p.t0_ns), p.object_id, node.model_id,
                                steps_in=len(obs))
        node.publish(out, p.feature)
        node.predictions += 1
        p.published = len(obs)
        if p.published < steps_in:
            keep.append(p)
    node._pending = keep
