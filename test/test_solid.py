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
"""The solid a whole cloud encloses (shapes.solid) and the planner's body and physics check that weigh it."""
from __future__ import annotations

import numpy as np
import pytest

from physdyn_ros import geometry as geo
from physdyn_ros.planning import body_from_cloud
from physdyn_ros.shapes.core import convex_hull, mass_properties
from physdyn_ros.shapes.procedural import make_procedural
from physdyn_ros.shapes.solid import solid_mass_properties


@pytest.mark.parametrize("category, index", [("legged", 3), ("legged", 20), ("dumbbell", 5), ("ring", 7),
                                             ("box", 2), ("mug", 4)])
def test_the_solid_of_a_whole_cloud_weighs_like_the_object(category, index):
    """Volume, centre of mass and radii of gyration of the cloud's solid are the mesh's within the voxels'
    resolution, for concave objects too, where the hull's are far off."""
    shape = make_procedural(category, index, seed=0)
    pts = np.asarray(shape.points, dtype=np.float64)  # object frame: the true COM is the origin
    true = shape.mass_properties(density=1.0)
    solid = solid_mass_properties(pts, density=1.0)
    size = float(shape.extents.max())
    assert 0.5 < solid.volume / true.volume < 2.0  # thin walls and rings come out up to a voxel thick
    assert np.linalg.norm(solid.com) < 0.06 * size
    true_gyration = np.sqrt(np.diag(true.inertia) / true.mass)
    gyration = np.sqrt(np.diag(solid.inertia) / solid.mass)
    assert gyration == pytest.approx(true_gyration, rel=0.12)
    if category in ("legged", "dumbbell", "ring"):  # the hull fills the gaps: worse on volume and inertia
        v, f = convex_hull(pts)
        hull = mass_properties(v, f, density=1.0)
        assert abs(np.log(hull.volume / true.volume)) > abs(np.log(solid.volume / true.volume))
        hull_gyration = np.sqrt(np.diag(hull.inertia) / hull.mass)
        assert np.abs(hull_gyration / true_gyration - 1).max() > np.abs(gyration / true_gyration - 1).max()


@pytest.mark.parametrize("points, match", [
    (np.full((50, 3), np.nan), "NaN"),
    (np.zeros((5, 3)), "cloud"),
    (np.zeros((100, 3)), "spans"),
])
def test_bad_clouds_name_the_problem(points, match):
    with pytest.raises(ValueError, match=match):
        solid_mass_properties(points)


def test_a_scaled_shape_with_given_mass_properties_is_refused():
    from physdyn_ros.shapes.core import shape_from_points

    pts = np.asarray(make_procedural("box", 1, seed=0).points, dtype=np.float64)
    shape = shape_from_points(pts, solid=solid_mass_properties(pts))
    assert shape.mass_properties(density=2.0).mass == pytest.approx(2.0 * shape.solid.volume)
    with pytest.raises(ValueError, match="scaled"):
        shape.mass_properties((2.0, 1.0, 1.0))


def test_push_velocities_of_a_legged_object_match_pybullet_with_the_solid():
    """A table pushed at its top: the velocities the planner asks the model about are those pybullet gives
    the impulse when the body weighs the cloud's solid; the hull (centre of mass centimetres low, wrong inertia)
    gets the spin and tilt wrong. The test that the whole-cloud body was built for."""
    from physdyn_ros.sim.simulator import SimConfig, Simulator

    shape = make_procedural("legged", 3, seed=0)
    errors = {}
    with Simulator(SimConfig()) as sim:
        sim.spawn(shape, xy=(0.0, 0.0), yaw=0.4)
        pos, quat, _, _ = sim.state()
        pts = np.asarray(shape.points, dtype=np.float64)
        cloud = geo.quat_rotate(np.broadcast_to(quat, (len(pts), 4)), pts) + pos
        saved = sim.client.saveState()
        for whole in (True, False):
            body = body_from_cloud(cloud, mass=sim.mass, whole=whole)
            assert body.source == ("solid" if whole else "hull")
            lo, hi = body.height_range(0.0, 1.0)
            d = np.array([[1.0, 0.3]]) / np.hypot(1.0, 0.3)
            contact, _ = body.contacts(d, np.array([0.4]), np.array([lo + 0.9 * (hi - lo)]))
            v = np.array([[0.6 * d[0, 0], 0.6 * d[0, 1], 0.0]])
            w = body.angular_velocity(v, contact)[0]
            sim.client.restoreState(saved)
            sim.apply_impulse(sim.mass * v[0], contact[0])
            _, _, _, w_sim = sim.state()
            errors[whole] = float(np.linalg.norm(w - w_sim) / np.linalg.norm(w_sim))
        sim.client.removeState(saved)
    assert errors[True] < 0.4  # the table's legs come out a voxel thick: its tilt a little slow
    assert errors[False] > 3 * errors[True]  # the hull: 3.5 times the spin it gets


def test_the_physics_check_simulates_the_planners_body():
    """Re-simulated with a whole cloud's body, the hull weighs what the body weighs (mass, centre of mass,
    inertia): the velocities the planner checks refer to that body."""
    pytest.importorskip("pybullet")
    from physdyn_ros.planning.sim_model import PybulletModel

    shape = make_procedural("legged", 3, seed=0)
    cloud = np.asarray(shape.points, dtype=np.float64) + np.array([0.1, -0.2, 0.3])
    body = body_from_cloud(cloud, mass=1.7, whole=True)
    with PybulletModel() as model:
        code = model.encode(cloud, body)
        mp = code.shape.mass_properties(density=model.config.density)
        assert code.centroid == pytest.approx(body.com)
        assert mp.mass == pytest.approx(1.7)
        assert mp.inertia / mp.mass == pytest.approx(body.inertia_per_mass)
        hull = model.encode(cloud)  # without a body: the uniform hull as before
        assert hull.shape.solid is None
        assert np.linalg.norm(hull.centroid - body.com) > 0.01


def test_reweigh_turns_the_hulls_velocities_into_the_solids_for_the_same_impulse():
    """The physics check's conversion: the angular velocity the solid gets from the impulse that gives the hull
    body its velocities is the solid body's own response to that impulse at that contact."""
    shape = make_procedural("legged", 3, seed=0)
    cloud = np.asarray(shape.points, dtype=np.float64) + np.array([0.2, 0.1, 0.25])
    hull = body_from_cloud(cloud, mass=2.0)
    solid = body_from_cloud(cloud, mass=2.0, whole=True)
    d = np.array([[0.6, 0.8], [1.0, 0.0], [0.0, -1.0]])
    lo, hi = hull.height_range(0.0, 1.0)
    contacts, _ = hull.contacts(d, np.array([0.5, -0.3, 0.0]), np.array([hi - 0.01, lo + 0.01, 0.5 * (lo + hi)]))
    v = np.concatenate([0.7 * d, np.zeros((3, 1))], axis=1)
    w_hull = hull.angular_velocity(v, contacts)
    assert hull.reweigh(solid, v, w_hull) == pytest.approx(solid.angular_velocity(v, contacts), rel=1e-9, abs=1e-9)
    assert hull.reweigh(hull, v, w_hull) == pytest.approx(w_hull)
    assert np.abs(w_hull - solid.angular_velocity(v, contacts)).max() > 0.5  # the two disagree: the test bites
