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
"""Synthetic depth-camera clouds of a table with objects (numpy only): for tests and bench/bench_perception.py.

The camera sees the table top (a rectangle at z = 0) and the faces of each object that face it (back faces
culled, bottom faces never seen; no occlusion between objects), with Gaussian depth noise, and reports the
points in its optical frame (REP 103: z forward, x right, y down), in random order like an unorganized cloud.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .frames import RigidTransform, camera_optical_pose

CAMERA_EYE = (0.6, 0.0, 0.45)  # the sim node's default camera
CAMERA_TARGET = (0.0, 0.0, 0.05)


@dataclass(frozen=True)
class ObjectSpec:
    kind: str  # "box" or "cylinder"
    x: float
    y: float
    yaw: float
    half: tuple[float, float, float]  # box half extents; cylinder: (radius, radius, half height)

    def moved(self, dx: float = 0.0, dy: float = 0.0, dyaw: float = 0.0) -> "ObjectSpec":
        return replace(self, x=self.x + dx, y=self.y + dy, yaw=self.yaw + dyaw)


#: Three objects 12-20 cm apart, in view of the default camera.
DEFAULT_OBJECTS = (
    ObjectSpec("box", 0.05, -0.15, 0.4, (0.05, 0.03, 0.04)),
    ObjectSpec("cylinder", -0.08, 0.02, 0.0, (0.035, 0.035, 0.06)),
    ObjectSpec("box", 0.12, 0.14, -0.7, (0.04, 0.04, 0.025)),
)


@dataclass
class SyntheticScene:
    points: np.ndarray  # (N, 3) float32, camera optical frame
    camera: RigidTransform  # camera optical frame -> table frame
    objects: list[np.ndarray]  # each object's points, table frame, without noise
    table_points: int
    centres: np.ndarray  # (n, 3) table frame: each object's true centre of mass (uniform solid box / cylinder)

    @property
    def centroids(self) -> np.ndarray:
        """(n, 3) the centroid of each object's visible points (what a model without a centre-of-mass head
        reports)."""
        return np.array([o.mean(axis=0) for o in self.objects])


def _yaw(points: np.ndarray, yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return points @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T


def _object_surface(spec: ObjectSpec, n: int, eye: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """About n points on the faces of the object that face the camera, table frame."""
    hx, hy, hz = spec.half
    centre = np.array([spec.x, spec.y, hz])
    cand = 4 * n  # culling keeps about half; draw more, then trim
    if spec.kind == "cylinder":
        r = hx
        side, top = 2 * np.pi * r * 2 * hz, np.pi * r * r
        on_top = rng.random(cand) < top / (side + top)
        ang = rng.uniform(0, 2 * np.pi, cand)
        rad = np.where(on_top, r * np.sqrt(rng.random(cand)), r)
        local = np.column_stack([rad * np.cos(ang), rad * np.sin(ang),
                                 np.where(on_top, hz, rng.uniform(-hz, hz, cand))])
        normal = np.where(on_top[:, None], [0.0, 0.0, 1.0],
                          np.column_stack([np.cos(ang), np.sin(ang), np.zeros(cand)]))
    else:
        areas = np.array([hy * hz, hy * hz, hx * hz, hx * hz, hx * hy])  # +x, -x, +y, -y, top
        face = rng.choice(5, cand, p=areas / areas.sum())
        local = rng.uniform(-1, 1, (cand, 3)) * np.array(spec.half)
        axis = np.array([0, 0, 1, 1, 2])[face]
        sign = np.array([1.0, -1.0, 1.0, -1.0, 1.0])[face]
        local[np.arange(cand), axis] = sign * np.array(spec.half)[axis]
        normal = np.zeros((cand, 3))
        normal[np.arange(cand), axis] = sign
    world = _yaw(local, spec.yaw) + centre
    facing = np.einsum("ij,ij->i", _yaw(normal, spec.yaw), eye - world) > 0
    return world[facing][:n]


def tabletop_scene(n_points: int = 100_000, objects=DEFAULT_OBJECTS, object_share: float = 0.15,
                   noise: float = 0.001, table_half=(0.4, 0.3), eye=CAMERA_EYE, target=CAMERA_TARGET,
                   rng: np.random.Generator | None = None) -> SyntheticScene:
    """A cloud of n_points: object_share of them on the objects (split by visible area), the rest on the table
    (minus the objects' footprints)."""
    rng = rng if rng is not None else np.random.default_rng(0)
    eye = np.asarray(eye, dtype=np.float64)
    objs = list(objects)
    n_obj = int(round(n_points * object_share)) if objs else 0
    weights = np.array([s.half[0] * s.half[1] + s.half[2] * (s.half[0] + s.half[1]) for s in objs])
    counts = np.floor(n_obj * weights / weights.sum()).astype(int) if objs else np.zeros(0, int)
    surfaces = [_object_surface(s, int(k), eye, rng) for s, k in zip(objs, counts)]
    n_table = n_points - sum(len(p) for p in surfaces)
    table = np.column_stack([rng.uniform(-table_half[0], table_half[0], 2 * n_table),
                             rng.uniform(-table_half[1], table_half[1], 2 * n_table), np.zeros(2 * n_table)])
    free = np.ones(len(table), dtype=bool)
    for s in objs:  # no table under an object
        local = _yaw(table - [s.x, s.y, 0.0], -s.yaw)
        if s.kind == "cylinder":
            free &= np.hypot(local[:, 0], local[:, 1]) > s.half[0]
        else:
            free &= (np.abs(local[:, 0]) > s.half[0]) | (np.abs(local[:, 1]) > s.half[1])
    table = table[free][:n_table]
    world = np.vstack([table] + surfaces)
    camera = camera_optical_pose(eye, target)
    cam = camera.inverse().apply(world)
    cam += rng.normal(0.0, noise, cam.shape) * (np.abs(cam[:, 2:3]) / 0.7)  # depth-proportional noise
    order = rng.permutation(len(cam))
    centres = np.array([[s.x, s.y, s.half[2]] for s in objs]).reshape(-1, 3)
    return SyntheticScene(points=cam[order].astype(np.float32), camera=camera, objects=surfaces,
                          table_points=len(table), centres=centres)
