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
"""The Simulator with several objects keyed by id (the sim node's table), and its single-object API unchanged."""
from __future__ import annotations

import numpy as np
import pytest

from physdyn_ros.shapes import resolve_shape
from physdyn_ros.sim import SimConfig, Simulator
from physdyn_ros.sim.simulator import DEFAULT_ID


@pytest.fixture(scope="module")
def box():
    return resolve_shape("box", 0, "")  # 7.7 x 21.2 x 6.0 cm


@pytest.fixture
def sim():
    with Simulator(SimConfig(collision="hull")) as s:
        yield s


def test_objects_are_added_replaced_and_removed_by_id(sim, box):
    sim.spawn(box, object_id="a", xy=(0.0, 0.0))
    sim.spawn(box, object_id="b", xy=(0.3, 0.0), yaw=0.5)
    sim.spawn(box, object_id="c", xy=(-0.3, 0.1))
    assert sim.ids == ["a", "b", "c"]
    states = sim.states()
    np.testing.assert_allclose([states[k][0][:2] for k in "abc"], [[0, 0], [0.3, 0], [-0.3, 0.1]], atol=1e-3)
    # re-using an id replaces that object only
    sim.spawn(box, object_id="b", xy=(0.0, 0.4), scale=(0.5, 0.5, 0.5))
    assert sim.ids == ["a", "c", "b"] and sim.get("b").mass == pytest.approx(sim.get("a").mass / 8, rel=1e-6)
    np.testing.assert_allclose(sim.state("b")[0][:2], [0.0, 0.4], atol=1e-3)
    np.testing.assert_allclose(sim.state("a")[0][:2], [0.0, 0.0], atol=1e-3)
    # the single-object API needs an id now, and says so
    with pytest.raises(RuntimeError, match="3 objects in the simulator .*name one"):
        sim.state()
    with pytest.raises(RuntimeError, match="name one"):
        sim.step_frame()
    with pytest.raises(ValueError, match="unknown object_id 'zz'"):
        sim.state("zz")
    sim.remove("c")
    assert sim.ids == ["a", "b"]
    with pytest.raises(ValueError, match="unknown object_id 'c'"):
        sim.remove("c")
    sim.remove()
    assert sim.ids == [] and sim.body is None and sim.shape is None
    # the single-object API: spawn without an id rebuilds the world with one object
    sim.spawn(box, object_id="x", xy=(0.5, 0.5))
    sim.spawn(box)
    assert sim.ids == [DEFAULT_ID] and sim.mass == sim.get(DEFAULT_ID).mass > 0


def test_overlapping_spawn_is_refused_and_the_world_is_kept(sim, box):
    width = float(box.extents[0])
    sim.spawn(box, object_id="a", xy=(0.0, 0.0))
    sim.spawn(box, object_id="b", xy=(width + 0.001, 0.0))  # 1 mm apart: fine
    before = {k: s[0].copy() for k, s in sim.states().items()}
    with pytest.raises(ValueError, match=r"'c' at \(0.020, 0.000\) m would overlap 'a'"):
        sim.spawn(box, object_id="c", xy=(0.02, 0.0))
    # replacing b by a body that overlaps a is refused too, and b stays
    with pytest.raises(ValueError, match="'b' .* would overlap 'a'"):
        sim.spawn(box, object_id="b", xy=(width - 0.01, 0.0))
    assert sim.ids == ["a", "b"] and not sim.overlaps("a")
    for k, s in sim.states().items():
        np.testing.assert_allclose(s[0], before[k], atol=1e-9)
    # replacing an object in place never collides with itself
    sim.spawn(box, object_id="a", xy=(-0.01, 0.0))


def test_pushed_object_moves_others_stay_and_objects_collide(sim, box):
    width = float(box.extents[0])
    sim.spawn(box, object_id="a", xy=(0.0, 0.0))
    sim.spawn(box, object_id="b", xy=(0.25, 0.0))
    sim.spawn(box, object_id="c", xy=(0.0, 0.5))
    start = {k: s[0].copy() for k, s in sim.states().items()}
    v, _ = sim.apply_impulse(np.array([2.5, 0.0, 0.0]) * sim.get("a").mass, start["a"], object_id="a")
    assert v[0] == pytest.approx(2.5, abs=1e-4)  # plus what settling the later objects left
    for _ in range(90):
        sim.step()
    end = {k: s[0] for k, s in sim.states().items()}
    # alone, a would slide v^2 / (2 mu g) = 0.64 m; b stops it and is knocked on; neither passes through
    assert end["a"][0] < end["b"][0] - 0.95 * width, (end["a"], end["b"])
    assert end["b"][0] - start["b"][0] > 0.05
    assert np.linalg.norm(end["c"] - start["c"]) < 1e-3  # the object out of the way stays
    assert not sim.overlaps("a") and not sim.overlaps("b")


def test_one_object_world_is_rebuilt_per_spawn(sim, box):
    """The single-object path (data generation) depends only on its inputs, whatever came before."""
    def run(s: Simulator) -> np.ndarray:
        s.spawn(box, yaw=0.3, friction=0.4)
        s.apply_impulse(np.array([0.3, 0.1, 0.0]), s.state()[0] + [0.0, 0.02, 0.01])
        return np.array([s.step_frame()[0] for _ in range(20)])

    with Simulator(SimConfig(collision="hull")) as fresh:
        ref = run(fresh)
    sim.spawn(box, object_id="a", xy=(0.0, 0.3))
    sim.spawn(box, object_id="b", xy=(0.4, 0.0))
    np.testing.assert_array_equal(run(sim), ref)


def test_spawning_again_and_again_frees_the_collision_shapes():
    """Review finding: replaced, refused and removed bodies left their collision shapes in the world (a sim node
    that spawns hundreds of objects grew). Every shape made is freed with its body, except the live ones."""
    from physdyn_ros.shapes import make_procedural
    from physdyn_ros.sim.simulator import Simulator

    shape = make_procedural("box", 1)
    with Simulator() as sim:
        made, freed = [], []
        create, remove = sim.client.createCollisionShape, sim.client.removeCollisionShape
        sim.client.createCollisionShape = lambda *a, **k: made.append(create(*a, **k)) or made[-1]
        sim.client.removeCollisionShape = lambda i: freed.append(i) or remove(i)
        for _ in range(5):
            sim.spawn(shape, object_id="a")  # add, then replace four times
        sim.spawn(shape, xy=(0.5, 0.0), object_id="b")
        with pytest.raises(ValueError, match="overlap"):
            sim.spawn(shape, xy=(0.5, 0.0), object_id="c")  # refused
        sim.remove("b")
        assert sorted(freed) == sorted(i for i in made if i != sim.get("a").collision)
