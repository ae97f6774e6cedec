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
"""The simulation core against physics: friction, toppling, impulses, frames, recording rules (real pybullet)."""
from __future__ import annotations

import numpy as np
import pytest

from physdyn_ros.conventions import DT, GRAVITY
from physdyn_ros.shapes import convex_hull, make_procedural, make_shape
from physdyn_ros.sim import (PushConfig, SimConfig, Simulator, record, simulate_from_state, simulate_push,
                             tilt_angle)
from physdyn_ros.sim.simulator import quat_to_matrix, yaw_quat


@pytest.fixture(scope="module", autouse=True)
def _vhacd_cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("PHYSDYN_CACHE", str(tmp_path_factory.mktemp("physdyn_cache")))
    yield
    mp.undo()


@pytest.fixture(scope="module")
def sim():
    s = Simulator(SimConfig())
    yield s
    s.close()


def box(dims, name="box"):
    corners = np.array([[x, y, z] for x in (-.5, .5) for y in (-.5, .5) for z in (0, 1)]) * np.asarray(dims)
    v, f = convex_hull(corners)
    return make_shape(name, "box", v, f, convex=True)


@pytest.mark.parametrize("mu", [0.5, 0.3])
def test_stopping_distance_matches_coulomb_friction(sim, mu):
    flat = box([0.2, 0.2, 0.05])
    v0 = 2.0
    sim.spawn(flat, friction=mu)
    start = sim.state()[0]
    sim.set_velocity([v0, 0, 0], [0, 0, 0])
    rec = record(sim, num_frames=40)
    travelled = rec["pos"][-1, 0] - start[0]
    expected = v0 ** 2 / (2 * mu * GRAVITY)
    assert travelled == pytest.approx(expected, rel=0.10)
    stop_time = (rec["length"] - 1) * DT
    assert stop_time == pytest.approx(v0 / (mu * GRAVITY), abs=0.1 + sim.config.rest_frames * DT)
    assert rec["topple_index"] == -1
    assert np.all(rec["lin_vel"][rec["length"]:] == 0)


def test_tall_object_pushed_high_topples_flat_box_does_not(sim):
    tall = box([0.05, 0.05, 0.3], "tall")
    flat = box([0.3, 0.3, 0.05], "flat")
    for shape, should_topple in ((tall, True), (flat, False)):
        sim.spawn(shape)
        pos, _, _, _ = sim.state()
        top = shape.bounds[1, 2]
        point = pos + [-0.03 if shape is tall else -0.15, 0, top * 0.9]
        sim.apply_impulse(np.array([1.5 * sim.mass, 0, 0]), point)
        rec = record(sim, num_frames=61)
        assert (rec["topple_index"] >= 0) == should_topple, shape.name
        if should_topple:
            t = rec["topple_index"]
            assert np.all(rec["toppled"][t:]) and not np.any(rec["toppled"][:t])
            assert tilt_angle(rec["quat"][t]) > np.pi / 4 >= tilt_angle(rec["quat"][t - 1])


def test_spawn_rests_upright_with_yaw_and_reports_object_frame(sim):
    mug = make_procedural("mug", 1)  # non-diagonal inertia: principal inertial frame
    scale = np.array([1.2, 0.8, 1.1])
    sim.spawn(mug, scale=scale, xy=(0.3, -0.2), yaw=0.7)
    assert sim._q_inertial[3] < 0.9999  # the frame conversion is exercised
    pos, q, v, w = sim.state()
    np.testing.assert_allclose(pos[:2], [0.3, -0.2], atol=2e-3)
    bottom = -mug.bounds[0, 2] * scale[2]
    assert bottom < pos[2] < bottom + 0.003  # ~1 mm Bullet margin
    np.testing.assert_allclose(tilt_angle(q), 0, atol=0.01)
    assert abs(q[2] - np.sin(0.35)) < 0.01 and q[3] > 0
    np.testing.assert_allclose(v, 0, atol=1e-9)
    # The world hull computed from the reported pose touches the plane.
    hull = (mug.hull()[0] * scale) @ quat_to_matrix(q).T + pos
    assert 0 <= hull[:, 2].min() < 0.003
    # set_pose / state round trip in the object frame.
    q_new = np.array([0.1, -0.2, 0.3, 0.9])
    q_new /= np.linalg.norm(q_new)
    sim.set_pose([0, 0, 1], q_new)
    np.testing.assert_allclose(sim.state()[1], q_new, atol=1e-7)
    # The inertia used is that of the true scaled geometry.
    np.testing.assert_allclose(sim.inertia, mug.mass_properties(scale, sim.config.density).inertia, rtol=1e-9)


def test_apply_impulse_is_rigid_body_impulse(sim):
    b = box([0.1, 0.2, 0.1])
    sim.spawn(b, yaw=0.3)
    pos, q, _, _ = sim.state()
    j = np.array([0.2, -0.1, 0.05])
    point = pos + [0.03, 0.05, 0.02]
    v, w = sim.apply_impulse(j, point)
    np.testing.assert_allclose(v, j / sim.mass, rtol=1e-9)
    r = quat_to_matrix(q)
    np.testing.assert_allclose(r @ sim.inertia @ r.T @ w, np.cross(point - pos, j), rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(sim.state()[2], v)


def test_simulate_push_arrays_and_recording_rules():
    rng = np.random.default_rng(0)
    shape = make_procedural("cylinder", 2)
    with Simulator() as sim:
        outs = [simulate_push(sim, shape, rng, num_frames=61) for _ in range(6)]
        varied = simulate_push(sim, shape, np.random.default_rng(1), vary_friction=True, num_frames=61)
    push = PushConfig()
    for out in outs:
        assert out["pos"].shape == (61, 3) and out["quat"].shape == (61, 4) and out["toppled"].dtype == bool
        assert out["pos"].dtype == np.float32
        n = int(out["length"])
        assert 1 <= n <= 61
        # Padding after rest: frozen pose, zero velocities.
        assert np.all(out["lin_vel"][n:] == 0) and np.all(out["ang_vel"][n:] == 0)
        assert np.all(out["pos"][n:] == out["pos"][n - 1])
        np.testing.assert_allclose(np.linalg.norm(out["quat"], axis=1), 1, atol=1e-5)
        ext = shape.extents * out["scale"]
        assert np.all(ext >= push.size_limits[0] - 1e-6) and np.all(ext <= push.size_limits[1] + 1e-6)
        assert out["friction"] == pytest.approx(0.5)
        assert np.linalg.norm(out["lin_vel"][0]) <= push.max_speed + 1e-3
        assert np.linalg.norm(out["ang_vel"][0]) <= push.max_spin + 1e-2
        np.testing.assert_allclose(out["lin_vel"][0], out["impulse"] / out["mass"], rtol=1e-4, atol=1e-6)
        ti = int(out["topple_index"])
        assert (ti >= 0) == bool(out["toppled"].any())
    assert 0.35 <= varied["friction"] <= 0.65
    # Same generator state -> identical simulation (fresh world per spawn).
    a = simulate_push(None, shape, np.random.default_rng(5), num_frames=61)
    b = simulate_push(None, shape, np.random.default_rng(5), num_frames=61)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_simulate_from_state_reproduces_and_accepts_clouds():
    shape = box([0.15, 0.1, 0.06])
    with Simulator() as sim:
        sim.spawn(shape, yaw=0.4)
        sim.set_velocity([1.0, 0.5, 0], [0, 0, 3.0])
        pos, q, v, w = sim.state()
        ref = record(sim, 61)
    again = simulate_from_state(shape, (1, 1, 1), pos, q, v, w, friction=0.5, num_frames=61)
    np.testing.assert_allclose(again["pos"][-1], ref["pos"][-1], atol=0.01)
    # A raw cloud (its hull is the collision shape): a box cloud behaves like the box.
    cloud = shape.points
    hull_run = simulate_from_state(cloud, (1, 1, 1), pos, q, v, w, friction=0.5, num_frames=61)
    assert hull_run["pos"].shape == (61, 3)
    np.testing.assert_allclose(hull_run["pos"][-1], ref["pos"][-1], atol=0.03)
    # Friction +20 % stops sooner.
    hi = simulate_from_state(cloud, (1, 1, 1), pos, q, v, w, friction=0.6, num_frames=61)
    assert np.linalg.norm(hi["pos"][-1, :2] - pos[:2]) < np.linalg.norm(hull_run["pos"][-1, :2] - pos[:2])


def test_simulate_from_state_starts_with_the_contacts_of_a_resting_object():
    """A fast tilting push of a settled prism (pybullet_data's, as the planning bench meets it: 0.6 m/s, 24 rad/s
    about a horizontal axis) leaves it upright; re-simulated from the same state it must too. A body teleported
    onto the table and launched at once meets it with no contacts and toppled on the third frame."""
    from physdyn_ros.shapes import resolve_shape

    shape = resolve_shape("pybullet_data", 5)
    v, w = np.array([0.49, 0.35, 0.0]), np.array([13.8, -16.4, 12.0])
    with Simulator(SimConfig(collision="parts")) as sim:
        sim.spawn(shape, xy=(0.0, 0.0), yaw=-0.8475)
        pos, q, _, _ = sim.state()
        sim.set_velocity(v, w)
        ref = record(sim, 76)
        scale = sim.scale
    again = simulate_from_state(shape, scale, pos, q, v, w, friction=0.5, num_frames=76,
                                config=SimConfig(collision="parts"))
    assert ref["topple_index"] == -1 and again["topple_index"] == -1
    np.testing.assert_allclose(again["pos"][0], pos, atol=1e-9)  # the run starts exactly at the given pose
    np.testing.assert_allclose(again["lin_vel"][0], v, atol=1e-6)


def test_concave_shape_uses_cached_convex_decomposition(tmp_path):
    from physdyn_ros.sim import convex_decomposition

    cfg = SimConfig(vhacd_cache_dir=str(tmp_path))
    mug = make_procedural("mug", 0)
    path = convex_decomposition(mug, cfg)
    assert path.is_file() and path.parent == tmp_path
    mtime = path.stat().st_mtime_ns
    assert convex_decomposition(mug, cfg) == path and path.stat().st_mtime_ns == mtime  # cached
    with Simulator(cfg) as sim:
        sim.spawn(mug, scale=(1.3, 1.0, 0.7), yaw=1.0)
        pos, q, _, _ = sim.state()
        assert tilt_angle(q) < 0.02
        assert -mug.bounds[0, 2] * 0.7 - 0.003 < pos[2] < -mug.bounds[0, 2] * 0.7 + 0.006
        out = simulate_push(sim, mug, np.random.default_rng(0), num_frames=61)
        assert np.isfinite(out["pos"]).all()


def test_config_validation():
    with pytest.raises(ValueError):
        SimConfig(physics_hz=100)
    with pytest.raises(ValueError):
        SimConfig(collision="mesh")
    assert SimConfig(physics_hz=480).substeps == 32
    with Simulator() as sim:
        with pytest.raises(RuntimeError, match="spawn"):
            sim.state()
        with pytest.raises(ValueError):
            sim.spawn(box([0.1, 0.1, 0.1]), scale=(1, -1, 1))
        with pytest.raises(ValueError):
            sim.spawn(box([0.1, 0.1, 0.1]), friction=-0.1)
        np.testing.assert_allclose(yaw_quat(0.0), [0, 0, 0, 1])
