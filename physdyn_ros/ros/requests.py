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
"""Checks of the predictor's requests that need no node state: the reason of a refusal, as a RequestError."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .convert import pose_to_numpy, time_to_ns, twist_to_numpy, xyz_to_numpy

#: kg/m^3: the densities a pushed object can have (expanded polystyrene ~10, tungsten ~19,300); a request's
#: mass is checked against the cloud's hull volume with them.
MIN_DENSITY, MAX_DENSITY = 5.0, 25_000.0
#: A request's cloud and initial pose describe one object: its centre may lie at most this far (m) outside
#: the cloud's bounding sphere (a partial view's centroid lies a few cm from the centre of mass).
POSE_CLOUD_SLACK = 0.1


#: Stamps further apart than this (s) are not of one session: one is unset or from another clock.
ABSURD_GAP = 86_400.0
NS = 1e-9


class RequestError(ValueError):
    """A bad input: the reason is logged or returned to the caller; nothing is published."""


def check_feature_age(object_id: str, feat_ns: int, t_ns: int, max_age: float) -> None:
    """RequestError unless a shape feature stamped feat_ns can describe the object at a push at t_ns (ns);
    max_age s (0 = no limit) either way."""
    age = (t_ns - feat_ns) * NS
    if feat_ns <= 0:
        raise RequestError(f"shape feature of '{object_id}' has an unset stamp (0)")
    if abs(age) > ABSURD_GAP:
        raise RequestError(f"shape feature of '{object_id}' (stamp {feat_ns * NS:.3f} s) and the push "
                           f"(stamp {t_ns * NS:.3f} s) are {abs(age) / 86_400:.1f} days apart: one stamp is "
                           "absurd or from another clock (sim time vs wall time: use_sim_time)")
    if max_age > 0 and age < -max_age:
        raise RequestError(f"every shape feature of '{object_id}' is newer than the push: the oldest by "
                           f"{-age:.2f} s (max_feature_age {max_age:g} s); is the push stamped late?")
    if max_age > 0 and abs(age) > max_age:
        raise RequestError(f"shape feature of '{object_id}' is stale: {age:.2f} s older than the push "
                           f"(max_feature_age {max_age:g} s); is the perception node receiving clouds?")


def check_feature(feat: Any, object_id: str, model_id: str, table_frame: str, feature_dim: int) -> None:
    """RequestError unless a ShapeFeature comes from this model, in the table frame, with the model's width."""
    if feat.model_id != model_id:
        raise RequestError(f"shape feature of '{object_id}' comes from model '{feat.model_id}' but this node "
                           f"runs '{model_id}': run perception with the same model_path")
    if feat.header.frame_id != table_frame:
        raise RequestError(f"shape feature frame_id '{feat.header.frame_id}' is not the table frame "
                           f"'{table_frame}'")
    if len(feat.feature) != feature_dim:
        raise RequestError(f"shape feature has {len(feat.feature)} numbers, the model expects {feature_dim}")


def shape_code(feat: Any):
    """A ShapeFeature message -> the Predictor's ShapeCode."""
    from ..predictor import ShapeCode

    return ShapeCode(feature=np.asarray(feat.feature, dtype=np.float32), heading=float(feat.heading),
                     centroid=xyz_to_numpy(feat.centroid), half_extents=xyz_to_numpy(feat.half_extents),
                     num_points=int(feat.num_points), model_id=feat.model_id)


def ordered_bounds(bounds) -> str | None:
    """Parameter check of plan_table_bounds: x_min < x_max and y_min < y_max, all finite."""
    if len(bounds) == 4 and not (np.all(np.isfinite(bounds)) and bounds[0] < bounds[1] and bounds[2] < bounds[3]):
        return f"must be finite [x_min, x_max, y_min, y_max] with x_min < x_max and y_min < y_max, got {list(bounds)}"
    return None


def check_pose_on_cloud(position: np.ndarray, cloud: np.ndarray) -> None:
    """RequestError unless the initial position lies within the cloud's bounding sphere (plus slack)."""
    centre = cloud.mean(axis=0)
    radius = float(np.linalg.norm(cloud - centre, axis=1).max())
    gap = float(np.linalg.norm(np.asarray(position, dtype=np.float64) - centre))
    if gap > radius + POSE_CLOUD_SLACK:
        raise RequestError(f"initial_pose ({position[0]:.3f}, {position[1]:.3f}, {position[2]:.3f}) is {gap:.2f} m "
                           f"from the cloud's centre ({centre[0]:.3f}, {centre[1]:.3f}, {centre[2]:.3f}), outside "
                           f"the object (radius {radius:.2f} m): the cloud and the pose must describe the same "
                           "object in the table frame")


def check_mass(mass: float, shape) -> None:
    """RequestError when `mass` gives the object an impossible density (its hull volume from the cloud, or the
    box of the shape code's half extents as an upper bound)."""
    from ..shapes.core import convex_hull, mass_properties

    if isinstance(shape, np.ndarray):
        try:
            v, f = convex_hull(shape.astype(np.float64))
            volume = float(mass_properties(v, f, density=1.0).volume)
        except Exception as exc:  # noqa: BLE001 - a flat or degenerate cloud has no volume to check against
            raise RequestError(f"cloud has no usable convex hull to check the mass against: {exc}") from None
        what, low = "hull volume", MIN_DENSITY
    else:
        volume = float(np.prod(2.0 * np.asarray(shape.half_extents, dtype=np.float64)))
        # the box holds the solid with room to spare: its density is a lower bound of the object's
        what, low = "bounding-box volume", MIN_DENSITY / 10.0
    density = mass / max(volume, 1e-12)
    if not low <= density <= MAX_DENSITY:
        raise RequestError(f"mass {mass:g} kg is not plausible for this object: its {what} {volume * 1e3:.3g} L "
                           f"gives a density of {density:.3g} kg/m^3 (expected {low:g}-{MAX_DENSITY:g})")


def observed_steps(states: Sequence[Any], onset: Any = None):
    """Observed ObjectStates of frames 1..K after a push -> the Predictor's `observed` argument. onset: the push's
    start as the perception node tracks it (t0_ns, position, orientation, lin_vel, ang_vel: a PendingRefinement):
    the first state's velocity then comes from its pose's change since the onset
    (pose_tracking.first_cloud_velocity), not from the tracker's twist there."""
    from ..perception.pose_tracking import first_cloud_velocity
    from ..predictor import Observed

    pos, quat, lin, ang = [], [], [], []
    for s in states:
        try:
            p, q = pose_to_numpy(s.pose)
        except ValueError as exc:
            raise RequestError(f"observed state: {exc}") from None
        v, w = twist_to_numpy(s.twist)
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(w))):
            raise RequestError("observed state velocity is not finite")
        if onset is not None and not pos:
            tau = 1e-9 * (time_to_ns(s.header.stamp) - onset.t0_ns)
            try:
                v, w = first_cloud_velocity(tau, onset.position, onset.orientation, onset.lin_vel, onset.ang_vel,
                                            p, q)
            except ValueError as exc:
                raise RequestError(f"observed state: {exc}") from None
        pos.append(p)
        quat.append(q)
        lin.append(v)
        ang.append(w)
    return Observed(positions=np.array(pos).reshape(-1, 3), orientations=np.array(quat).reshape(-1, 4),
                    lin_vels=np.array(lin).reshape(-1, 3), ang_vels=np.array(ang).reshape(-1, 3))
