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
"""The sim's depth camera puts every point on the object's surface, at any resolution."""
from __future__ import annotations

import numpy as np
import pytest

from physdyn_ros.geometry import quat_to_matrix
from physdyn_ros.shapes import resolve_shape
from physdyn_ros.sim import SimConfig, Simulator
from physdyn_ros.sim.camera import CameraSpec, DepthCamera


@pytest.mark.parametrize("resolution", [(320, 240), (200, 150), (640, 360)])
def test_camera_points_lie_on_the_boxs_faces(resolution):
    """A box at five yaws before the sim node's default camera: the points' median distance to the box's faces is
    below 0.05 mm (unprojected through pixel centres they lay 0.3-2.5 mm off: half a pixel sideways and down)."""
    spec = CameraSpec.make((0.6, 0.0, 0.45), (0.0, 0.0, 0.05), resolution, 60.0)
    shape = resolve_shape("box", 9001)
    half = np.abs(shape.vertices).max(axis=0)
    for yaw in (0.3, 0.8, 1.3, 2.0, 2.6):
        with Simulator(SimConfig(friction=0.5, collision="hull")) as sim:
            sim.spawn(shape, xy=(0.0, 0.05), yaw=yaw, object_id="o")
            pos, q = (np.asarray(a, dtype=np.float64) for a in sim.states()["o"][:2])
            points = DepthCamera(sim).render(spec)
        local = (points - pos) @ quat_to_matrix(q)  # into the box's frame
        distance = np.abs(np.abs(local) - half).min(axis=1)
        assert len(points) > 100 and np.median(distance) < 5e-5, (yaw, 1e3 * np.median(distance))


def test_render_each_splits_the_points_by_object():
    """Two boxes: render_each gives each id its own points (on its own faces), together render's points."""
    spec = CameraSpec.make((0.6, 0.0, 0.45), (0.0, 0.0, 0.05), (320, 240), 60.0)
    shape = resolve_shape("box", 9001)
    half = np.abs(shape.vertices).max(axis=0)
    with Simulator(SimConfig(friction=0.5, collision="hull")) as sim:
        sim.spawn(shape, xy=(0.0, -0.2), yaw=0.4, object_id="left")
        sim.spawn(shape, xy=(0.0, 0.2), yaw=1.1, object_id="right")
        camera = DepthCamera(sim)
        each, points = camera.render_each(spec), camera.render(spec)
        states = sim.states()
    assert sorted(each) == ["left", "right"] and sum(len(v) for v in each.values()) == len(points)
    for oid, view in each.items():
        pos, q = (np.asarray(a, dtype=np.float64) for a in states[oid][:2])
        local = (view - pos) @ quat_to_matrix(q)
        assert np.abs(np.abs(local) - half).min(axis=1).max() < 1e-3, oid
