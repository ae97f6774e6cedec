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
"""A simulated depth camera: the objects' pixels of a pybullet TinyRenderer depth image, as table-frame points.

The sim node's `cloud_source: camera` sensor. The renderer draws visual shapes only, and bodies built from
collision vertices have none, so each object gets a collision-free, massless copy that the camera poses like the
object before it renders; physics and ray tests ignore the copies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

#: Pixels per image side the camera accepts (a 0-pixel image has no aspect ratio; TinyRenderer is CPU-bound).
MIN_PIXELS, MAX_PIXELS = 8, 4096
#: m: the depth range, tight for the depth buffer's precision (clips nothing on a tabletop).
NEAR, FAR = 0.05, 5.0


def points_differ(value: Sequence[float], other: Sequence[float] | None, other_name: str) -> str | None:
    """A parameter check: the eye and the target (`other`, None when not declared yet) must differ; the reason."""
    if other is None or len(value) != len(other):
        return None
    if np.linalg.norm(np.asarray(value, dtype=np.float64) - np.asarray(other, dtype=np.float64)) < 1e-9:
        return f"must differ from {other_name} {list(other)} (the camera looks from camera_eye to camera_target)"
    return None


@dataclass(frozen=True)
class CameraSpec:
    """Where the camera is and what it renders: eye and target in the table frame (m), image size (pixels),
    vertical field of view (degrees)."""

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    width: int
    height: int
    fov: float

    @classmethod
    def make(cls, eye: Sequence[float], target: Sequence[float], resolution: Sequence[int], fov: float
             ) -> "CameraSpec":
        """A checked spec; ValueError names the bad value."""
        if len(eye) != 3 or len(target) != 3:
            raise ValueError(f"camera eye and target need 3 coordinates each, got {list(eye)} and {list(target)}")
        if len(resolution) != 2:
            raise ValueError(f"camera resolution needs width and height, got {list(resolution)}")
        e, t = np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)
        if not (np.all(np.isfinite(e)) and np.all(np.isfinite(t))) or np.linalg.norm(t - e) < 1e-9:
            raise ValueError(f"camera eye {e.tolist()} and target {t.tolist()} must be finite and differ")
        w, h = (int(v) for v in resolution)
        if not (MIN_PIXELS <= w <= MAX_PIXELS and MIN_PIXELS <= h <= MAX_PIXELS):
            raise ValueError(f"camera resolution {w} x {h} must be {MIN_PIXELS}-{MAX_PIXELS} pixels a side")
        if not 1.0 <= float(fov) <= 170.0:
            raise ValueError(f"camera field of view {fov} must be 1-170 degrees")
        return cls(tuple(e.tolist()), tuple(t.tolist()), w, h, float(fov))


class DepthCamera:
    """Renders a Simulator's objects; keeps one visual copy per object id (forget() when it is removed)."""

    def __init__(self, sim) -> None:
        self.sim = sim
        self._visuals: dict[str, int] = {}

    def forget(self, object_id: str) -> None:
        """Drop the visual copy of an object that is removed or replaced."""
        uid = self._visuals.pop(object_id, None)
        if uid is not None:
            self.sim.client.removeBody(uid)

    def render(self, spec: CameraSpec) -> np.ndarray:
        """The table-frame points (N, 3) of the objects' pixels seen from spec.eye towards spec.target."""
        return self._pixels(spec)[0]

    def render_each(self, spec: CameraSpec) -> dict[str, np.ndarray]:
        """render's points split by the object they belong to: object id -> (N_k, 3); objects out of view or
        hidden behind others are absent."""
        points, body = self._pixels(spec)
        owner = {uid: oid for oid, uid in self._visuals.items()}
        owner.update({b.uid: oid for oid, b in self.sim.bodies.items()})
        ids = np.array([owner.get(int(u), "") for u in body], dtype=object)
        return {oid: points[ids == oid] for oid in dict.fromkeys(ids.tolist()) if oid}

    def _pixels(self, spec: CameraSpec) -> tuple[np.ndarray, np.ndarray]:
        """The objects' pixels as table-frame points (N, 3) and the pybullet body each shows (N,)."""
        eye, target = np.asarray(spec.eye, float), np.asarray(spec.target, float)
        width, height, fov = spec.width, spec.height, spec.fov
        fwd = target - eye
        fwd /= np.linalg.norm(fwd)
        up_hint = np.array([0.0, 0.0, 1.0]) if abs(fwd[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
        right = np.cross(fwd, up_hint)
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        c = self.sim.client
        bodies = {b.uid for b in self.sim.bodies.values()} | {self._visual_body(k) for k in self.sim.ids}
        if not bodies:
            return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
        view = c.computeViewMatrix(eye.tolist(), target.tolist(), up.tolist())
        proj = c.computeProjectionMatrixFOV(fov, width / height, NEAR, FAR)
        _, _, _, depth, seg = c.getCameraImage(width, height, view, proj, renderer=c.ER_TINY_RENDERER)
        depth = np.asarray(depth, dtype=np.float64).reshape(height, width)
        seg = np.asarray(seg).reshape(height, width)
        body = seg & ((1 << 24) - 1)  # seg = body + (link + 1) << 24
        mask = np.isin(body, list(bodies))  # object pixels only
        z = FAR * NEAR / (FAR - (FAR - NEAR) * depth[mask])  # OpenGL depth buffer -> distance along fwd
        v_idx, u_idx = np.nonzero(mask)
        tan = math.tan(math.radians(fov) / 2)
        # TinyRenderer samples each pixel at its integer corner, rows counted from the image's bottom: pixel
        # (u, v) of the returned image (rows from the top) sees the ray through (u, height - 1 - v). Pixel centres
        # put every point half a pixel off (1.6 mm sideways at 320 x 240 and 0.7 m), off the object's faces
        xn = (2.0 * u_idx / width - 1.0) * tan * width / height
        yn = (1.0 - 2.0 * (v_idx + 1.0) / height) * tan
        return eye + z[:, None] * (fwd + xn[:, None] * right + yn[:, None] * up), body[mask]

    def _visual_body(self, object_id: str) -> int:
        """The object's visual copy (made on first use), posed like the object now."""
        c, b = self.sim.client, self.sim.get(object_id)
        uid = self._visuals.get(object_id)
        if uid is None:
            vs = c.createVisualShape(c.GEOM_MESH, vertices=b.shape.vertices.tolist(),
                                     indices=b.shape.faces.reshape(-1).tolist(), meshScale=b.scale.tolist())
            uid = c.createMultiBody(baseMass=0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=vs)
            self._visuals[object_id] = uid
        pos, q, _, _ = self.sim.state(object_id)
        c.resetBasePositionAndOrientation(uid, pos.tolist(), q.tolist())
        return uid
