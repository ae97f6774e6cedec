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
"""The whole-push topple head: support descriptors, the probability rules, fitting, and the Predictor / evaluation
paths that apply it."""
from __future__ import annotations

import argparse
import math

import numpy as np
import pytest
import torch
import trimesh
from learn_support import random_checkpoint, tiny_dataset

from physdyn_ros import geometry as geo
from physdyn_ros.conventions import GRAVITY
from physdyn_ros.learn import rules, support
from physdyn_ros.predictor import compose_rotations
from physdyn_ros.learn.support import DESCRIPTOR_DIM, PUSH_DIM, SUPPORT_DIRECTIONS, SUPPORT_GAP_M, push_quantities, \
    resting_table, support_descriptors


def _surface(mesh: trimesh.Trimesh, n: int = 3000) -> np.ndarray:
    pts = np.asarray(mesh.sample(n, seed=0) if "seed" in mesh.sample.__code__.co_varnames else mesh.sample(n))
    return pts - pts.mean(axis=0)


def completed_cloud(points: np.ndarray, com: np.ndarray, table: float | None = None) -> np.ndarray:
    """(4N + 1, 3): the points (N, 3), their mirror images through the vertical planes x = com_x, y = com_y and
    both, and the centre of mass's foot on the table (resting_table), built explicitly: what support_descriptors
    reads off the points without building it."""
    pts, c = np.asarray(points, dtype=np.float64), np.asarray(com, dtype=np.float64)
    flips = np.array([[1.0, 1.0, 1.0], [-1.0, 1.0, 1.0], [1.0, -1.0, 1.0], [-1.0, -1.0, 1.0]])
    foot = np.array([c[0], c[1], resting_table(pts[:, 2], table)])
    return np.concatenate([(c + (pts - c)[None] * flips[:, None]).reshape(-1, 3), foot[None]])


def plain_descriptors(points: np.ndarray, com: np.ndarray) -> np.ndarray:
    """(DESCRIPTOR_DIM,) the descriptors of the points as they are, nothing completed: the support band from the
    lowest point and its hull, the points' second moments and tilt barriers (the reference of the tests below)."""
    z = points[:, 2]
    z0, height = z.min(), z.max() - z.min()
    base = points[z < z0 + max(support.BASE_BAND_M, support.BASE_BAND_REL * height)]
    reach, area = support._support_reach(base[:, :2], com[:2], support._DIRS)
    tilt = support._barriers(support._tilt_heights(points, com))
    return np.concatenate([[com[2] - z0, height, area], reach, np.mean((points - com) ** 2, axis=0), tilt])


def _reach(desc: np.ndarray, degrees: float) -> float:
    k = int(round(degrees / (360.0 / SUPPORT_DIRECTIONS)))
    return float(desc[3 + k])


def test_box_descriptors_are_its_statics():
    """A 0.2 x 0.1 x 0.3 m box standing on its base: COM 0.15 m up, the base reaches 0.1 m along x and 0.05 m
    along y, its area is 0.02 m^2."""
    pts = _surface(trimesh.creation.box(extents=(0.2, 0.1, 0.3)))
    com = np.zeros(3)  # the box's centroid is its centre of mass
    desc = support_descriptors(pts[None], com[None])[0]
    assert desc.shape == (DESCRIPTOR_DIM,)
    assert desc[0] == pytest.approx(0.15, abs=0.005) and desc[1] == pytest.approx(0.3, abs=0.005)
    assert desc[2] == pytest.approx(0.02, rel=0.15)
    for deg, want in ((0, 0.1), (180, 0.1), (90, 0.05), (270, 0.05)):
        assert _reach(desc, deg) == pytest.approx(want, abs=0.006), deg
    assert _reach(desc, 45) == pytest.approx(0.05 * math.sqrt(2), abs=0.008)


def test_a_lying_cylinder_rests_on_a_line_and_an_offset_com_lies_outside_its_support():
    """A cylinder on its side touches the table along a line: the support reaches along the axis, barely across
    it (a thin strip instead of a failed hull). A centre of mass moved past the base's edge gives a negative reach
    in that direction."""
    cyl = trimesh.creation.cylinder(radius=0.04, height=0.2, sections=64)
    cyl.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0]))  # axis along x
    desc = support_descriptors(_surface(cyl)[None], np.zeros((1, 3)))[0]
    assert _reach(desc, 0) == pytest.approx(0.1, abs=0.01)
    assert _reach(desc, 90) < 0.2 * _reach(desc, 0)  # the 3 mm band of a 4 cm radius: 1.5 cm across
    # a base that is exactly a line (a hull of it fails): a 1 mm strip
    rng = np.random.default_rng(0)
    line = np.c_[np.linspace(-0.1, 0.1, 50), np.zeros(50), np.zeros(50)]
    above = rng.uniform([-0.1, -0.05, 0.05], [0.1, 0.05, 0.1], (200, 3))
    strip = support_descriptors(np.concatenate([line, above])[None], np.array([[0.0, 0.0, 0.05]]))[0]
    assert _reach(strip, 0) == pytest.approx(0.101, abs=0.002) and _reach(strip, 90) == pytest.approx(0.001)
    box = _surface(trimesh.creation.box(extents=(0.1, 0.1, 0.1)))
    shifted = plain_descriptors(box, np.array([0.08, 0.0, 0.0]))
    assert _reach(shifted, 0) < -0.02 and _reach(shifted, 180) > 0.1
    # completed by its mirror images through the centre of mass, the support reaches past it both ways
    completed = support_descriptors(box[None], np.array([[0.08, 0.0, 0.0]]))[0]
    assert _reach(completed, 0) > 0.1 and _reach(completed, 180) > 0.1


def test_push_quantities_follow_the_tipping_barrier():
    desc = np.zeros((1, DESCRIPTOR_DIM))
    desc[0, 0] = 0.1  # centre of mass 10 cm up
    desc[0, 3:3 + SUPPORT_DIRECTIONS] = 0.05  # a round base of 5 cm radius
    desc[0, 3 + SUPPORT_DIRECTIONS:6 + SUPPORT_DIRECTIONS] = 0.001
    desc[0, 6 + SUPPORT_DIRECTIONS:] = np.where(np.arange(SUPPORT_DIRECTIONS) == 0, 0.02, 0.3)  # low barrier at +x
    q = push_quantities(desc, np.array([[1.0, 0.0, 0.0]]), np.zeros((1, 3)))[0]
    assert q.shape == (PUSH_DIM,)
    speed, front, barrier, kinetic = q[6], q[9], q[13], q[14]
    assert speed == pytest.approx(1.0) and front == pytest.approx(0.05)
    assert barrier == pytest.approx(GRAVITY * (math.hypot(0.1, 0.05) - 0.1))
    assert kinetic == pytest.approx(0.5)
    tilt_ahead, tilt_min, log_ahead = q[18], q[19], q[20]
    assert tilt_ahead == pytest.approx(0.02) and tilt_min == pytest.approx(0.02)
    assert log_ahead == pytest.approx(math.log((0.5 + 1e-6) / (0.02 + 1e-6)))
    sideways = push_quantities(desc, np.array([[0.0, 1.0, 0.0]]), np.zeros((1, 3)))[0]
    assert sideways[18] == pytest.approx(0.3)  # pushed along y: the barrier that way
    with pytest.raises(ValueError, match="one centre of mass each"):
        support_descriptors(np.zeros((2, 10, 3)), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="descriptors must be"):
        push_quantities(desc[:, :30], np.zeros((1, 3)), np.zeros((1, 3)))


def test_an_oblique_push_is_weighed_against_the_barrier_of_each_direction():
    """A bar on round weights (a dumbbell lying across y) rolls toward +-y with no barrier and tips over an end
    toward +-x: a push mostly along x with a small y component rolls it. The barrier straight ahead is the steep
    one; the last four columns find the roll (the energy toward +y against its barrier)."""
    desc = np.zeros((2, DESCRIPTOR_DIM))
    desc[:, 0], desc[:, 3:3 + SUPPORT_DIRECTIONS] = 0.05, 0.03
    tilt = np.full(SUPPORT_DIRECTIONS, 0.3)
    tilt[[SUPPORT_DIRECTIONS // 4, 3 * SUPPORT_DIRECTIONS // 4]] = 0.003  # +y and -y
    desc[:, 6 + SUPPORT_DIRECTIONS:] = tilt
    q = push_quantities(desc, np.array([[1.0, 0.2, 0.0], [1.0, 0.0, 0.0]]), np.zeros((2, 3)))
    assert q.shape == (2, PUSH_DIM)
    ratio, barrier, energy, cosine = q[0, PUSH_DIM - 4:]
    assert barrier == pytest.approx(0.003) and energy == pytest.approx(0.5 * 0.2 ** 2)
    assert ratio == pytest.approx(math.log((0.02 + 1e-6) / (0.003 + 1e-6)))
    assert cosine == pytest.approx(0.2 / math.hypot(1.0, 0.2))
    assert q[0, 18] == pytest.approx(0.3)  # the barrier ahead: the steep one
    straight = q[1, PUSH_DIM - 4:]  # straight along x: no energy toward y, the barrier ahead decides
    assert straight[1] == pytest.approx(0.3) and straight[3] == pytest.approx(1.0)


def test_tilt_barriers_tell_a_rolling_base_from_a_flat_one():
    """A cube of side 2a tilted 45 deg about a base edge raises its centre of mass from a to a sqrt(2): barrier
    g a (sqrt(2) - 1) toward each face. A round cylinder lying along x rolls across its axis with no barrier (its
    band of lowest points still reaches 1.5 cm that way), but tips over an end along its axis."""
    a = 0.05
    cube = trimesh.creation.box(extents=(2 * a, 2 * a, 2 * a))
    pts = np.concatenate([np.asarray(cube.sample(2000)), np.asarray(cube.vertices)])  # centred on the cube
    barrier = plain_descriptors(pts, np.zeros(3))[6 + SUPPORT_DIRECTIONS:]
    assert barrier.shape == (SUPPORT_DIRECTIONS,)
    for k in (0, 4, 8, 12):  # +x, +y, -x, -y
        assert barrier[k] == pytest.approx(GRAVITY * a * (math.sqrt(2) - 1), rel=1e-6)
    # the cube is its own mirror image: completing it changes no barrier
    completed = support_descriptors(pts[None], np.zeros((1, 3)))[0, 6 + SUPPORT_DIRECTIONS:]
    assert np.allclose(completed, barrier, rtol=0, atol=1e-12)
    cyl = trimesh.creation.cylinder(radius=0.04, height=0.2, sections=64)
    cyl.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0]))
    desc = support_descriptors(_surface(cyl)[None], np.zeros((1, 3)))[0]
    tilt = desc[6 + SUPPORT_DIRECTIONS:]
    across, along = tilt[4], tilt[0]
    assert across < 0.01 * along and across < GRAVITY * 0.001  # under 1 mm of rise rolling 45 deg
    assert along == pytest.approx(GRAVITY * (0.04 * math.cos(math.pi / 4) + 0.1 * math.sin(math.pi / 4) - 0.04),
                                  rel=0.05)
    assert _reach(desc, 90) > 0.01  # what the support polygon alone says: a 1.5 cm wide strip


def _view(points: np.ndarray, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """The points one depth camera sees from that direction (noise-free)."""
    from physdyn_ros.learn.views import visible

    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    d = np.array([[math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]])
    return points[visible(points[None], d)[0]]


def test_a_view_completed_on_the_table_has_the_whole_objects_statics():
    """One camera sees two sides and the top of a box standing on the table: the view's lowest points are two
    edges of the base, and nothing marks the far corner. Completed (the table's height and the mirror images
    through the centre of mass's vertical planes) the view gives the whole box's support, height and tilt
    barriers; the view alone does not."""
    box = trimesh.creation.box(extents=(0.2, 0.1, 0.3))
    pts = np.concatenate([_surface(box, 6000), np.asarray(box.vertices)])
    com, table = np.zeros(3), -0.15  # the box's centre of mass, the table under its base
    whole = plain_descriptors(pts, com)
    view = _view(pts, 40.0, 35.0)
    far = (view[:, 0] < -0.099).sum() / (pts[:, 0] < -0.099).sum()
    assert len(view) < 0.6 * len(pts) and far < 0.2  # the -x face is not seen (its edge pixels leak)
    seen = plain_descriptors(view, com)
    done = support_descriptors(view[None], com[None], table=np.array([table]))[0]
    reach = slice(3, 3 + SUPPORT_DIRECTIONS)
    tilt = slice(6 + SUPPORT_DIRECTIONS, None)
    assert np.abs(seen[reach] - whole[reach]).max() > 0.03  # the far corner's side of the base is missing
    assert np.abs(done[reach] - whole[reach]).max() < 0.008
    assert done[0] == pytest.approx(0.15, abs=1e-6) and done[1] == pytest.approx(0.3, abs=0.005)
    assert np.abs(done[tilt] - whole[tilt]).max() < 0.02 * whole[tilt].max()
    # a symmetric whole cloud on the table is unchanged by the completion (to the sampling's 1 mm asymmetry)
    assert np.allclose(support_descriptors(pts[None], com[None], table=np.array([table]))[0], whole,
                       atol=1e-3)


def test_descriptors_are_those_of_the_completed_cloud():
    """support_descriptors reads the mirror images off the points (no 4x cloud is built): on one-sided views it
    equals the plain descriptors of completed_cloud where the table is the lowest point, and all but the support
    polygon (whose band starts at the lowest point seen) where the table lies below it or just above."""
    rng = np.random.default_rng(0)
    polygon = slice(2, 3 + SUPPORT_DIRECTIONS)  # area and reach
    for _ in range(20):
        pts = np.asarray(trimesh.creation.box(extents=rng.uniform(0.05, 0.3, 3)).sample(1024))
        pts = pts[pts @ rng.normal(size=3) > -0.02]  # one side of it
        com = rng.normal(size=3) * 0.01
        low = pts[:, 2].min()
        for table in (low, low - rng.uniform(0.0, 0.03), low + 0.004):
            slow = plain_descriptors(completed_cloud(pts, com, table), com)
            fast = support_descriptors(pts[None], com[None], table=np.array([table]))[0]
            same = np.ones(len(fast), dtype=bool)
            if table != low:
                same[polygon] = False
            assert np.allclose(fast[same], slow[same], rtol=0, atol=1e-12)


def test_a_cloud_without_its_bottom_slice_keeps_its_support():
    """The perception node removes the points within 5 mm of the table plane: the base outline of a real cloud
    lies a few mm up, and the support is read there (within SUPPORT_GAP_M of the table; a band from the table
    would hold the foot alone). A view that has not seen its support at all (a ball from 60 deg above: its lowest
    point 2.5 cm up) rests on the foot of its centre of mass alone."""
    box = trimesh.creation.box(extents=(0.1, 0.06, 0.1))
    pts = np.concatenate([_surface(box, 6000), np.asarray(box.vertices)])
    com, table = np.zeros((1, 3)), np.array([-0.05])
    whole = support_descriptors(pts[None], com, table=table)[0]
    cut = pts[pts[:, 2] > table[0] + 0.005]
    seen = support_descriptors(cut[None], com, table=table)[0]
    reach = slice(3, 3 + SUPPORT_DIRECTIONS)
    assert whole[2] == pytest.approx(0.006, rel=0.1) and seen[2] == pytest.approx(whole[2], rel=0.15)
    assert np.abs(seen[reach] - whole[reach]).max() < 0.004
    assert seen[0] == pytest.approx(0.05, abs=1e-3) and seen[1] == pytest.approx(whole[1], abs=1e-3)  # from the table
    ball = _surface(trimesh.creation.icosphere(subdivisions=4, radius=0.05), 6000)
    top = _view(ball, 30.0, 60.0)
    assert top[:, 2].min() > -0.05 + SUPPORT_GAP_M
    alone = support_descriptors(top[None], np.zeros((1, 3)), table=np.array([-0.05]))[0]
    assert alone[2] < 1e-5 and np.abs(alone[reach]).max() < 0.0015  # a point, inflated by 1 mm


def test_a_table_the_object_cannot_rest_on_is_replaced_by_its_lowest_point():
    """The table height comes from the frame (z = 0 of the table frame): a cloud given in another frame (far
    above the table, or reaching below it) rests on its own lowest point instead."""
    z = np.array([0.02, 0.1, 0.3])
    assert resting_table(z, 0.0) == 0.0  # a view whose lowest visible point is 2 cm up
    assert resting_table(z, None) == 0.02 and resting_table(z, float("nan")) == 0.02
    assert resting_table(z, -0.5) == 0.02  # 52 cm under an object 28 cm tall: not its table
    assert resting_table(z, 0.05) == 0.02  # above the lowest point
    cloud = np.array([[0.1, 0.0, 0.3], [-0.1, 0.05, 0.02], [0.0, -0.05, 0.1]])
    # the centre of mass's height counts from the table it rests on, else from the lowest point
    com = np.array([[0.01, 0.0, 0.15]])
    assert support_descriptors(cloud[None], com, table=np.zeros(1))[0, 0] == pytest.approx(0.15)
    assert support_descriptors(cloud[None], com, table=np.array([-0.5]))[0, 0] == pytest.approx(0.13)
    assert support_descriptors(cloud[None], com)[0, 0] == pytest.approx(0.13)
    with pytest.raises(ValueError, match="one height per cloud"):
        support_descriptors(cloud[None], np.zeros((1, 3)), table=np.zeros(2))


def test_the_head_reads_the_descriptors_and_push_quantities_whole():
    """A head's inputs are the shape feature, the DESCRIPTOR_DIM descriptors and the PUSH_DIM push quantities;
    its numpy pass (assess) and its torch module agree, and descriptors of another width are refused."""
    from physdyn_ros.learn.topple import ToppleHead

    head = ToppleHead(8, 16, 2)
    assert head.in_dim == 8 + DESCRIPTOR_DIM + PUSH_DIM
    rng = np.random.default_rng(0)
    feature = rng.normal(size=(3, 8))
    box = _surface(trimesh.creation.box(extents=(0.1, 0.2, 0.3)))
    desc = support_descriptors(np.stack([box] * 3), np.zeros((3, 3)))
    vel, angvel = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    prob, _ = head.assess(feature, desc, vel, angvel)
    push = torch.from_numpy(push_quantities(desc, vel, angvel))
    want = head(torch.from_numpy(feature).float(), torch.from_numpy(desc).float(), push.float())
    assert prob == pytest.approx(want.detach().double().numpy(), abs=1e-5)
    for width in (22, DESCRIPTOR_DIM + 1):
        with pytest.raises(ValueError, match=f"needs \\(B, {DESCRIPTOR_DIM}\\) support descriptors"):
            head.assess(feature, np.zeros((3, width)), vel, angvel)


def test_whole_push_probability_is_the_heads_with_the_step_network_timing():
    step = np.array([[0.0, 0.1, 0.3, 0.2, 0.6, 0.5], [0.0, 0.01, 0.02, 0.02, 0.02, 0.02]])
    tilted = np.zeros_like(step, dtype=bool)
    tilted[1, 4:] = True
    per_step, whole = rules.whole_push_topple(step, np.array([0.2, 0.1]), tilted)
    assert whole.tolist() == [0.2, 1.0]  # a pose past 45 deg has toppled, whatever the head says
    assert per_step.max(axis=1).tolist() == pytest.approx([0.2, 1.0])
    assert np.all(per_step[:, 0] == 0) and np.all(np.diff(per_step, axis=1) >= 0)
    assert per_step[0, 2] == pytest.approx(0.2 * 0.3 / 0.6)  # the step network's timing, scaled


def test_the_heads_no_removes_the_step_networks_tilt():
    """A roll-out the step network let tilt (its probability > 0.5) keeps the tilt only if the head agrees."""
    h = 10
    d_rot = np.tile(np.array([0.02, 0.01, 0.05]), (2, h, 1))  # tilting and turning, under 45 deg in total
    ang = np.tile(np.array([0.3, 0.15, 0.75]), (2, h + 1, 1))
    prob = np.full((2, h + 1), 0.9)
    prob[:, 0] = 0.0
    out = rules.topple_with_head(prob, np.array([0.1, 0.8]), d_rot, ang, 0,
                                 lambda rows, d: compose_rotations(np.array([[0.0, 0.0, 0.0, 1.0]] * len(rows)), d))
    assert np.all(d_rot[0, :, :2] == 0) and np.all(ang[0, 1:, :2] == 0)  # head says no: flat, pure yaw
    assert np.all(d_rot[0, :, 2] == 0.05)
    assert np.all(d_rot[1, :, :2] != 0)  # head says yes: the tilt stays
    assert out[0].max() == pytest.approx(0.1) and out[1].max() == pytest.approx(0.8)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A tiny random-weight model whose topple head is fitted by `physdyn fit-topple` on the tiny dataset."""
    from physdyn_ros.learn import topple_fit

    tmp = tmp_path_factory.mktemp("topple")
    src = random_checkpoint(tmp / "src.pt")
    out = tmp / "fitted.pt"
    args = argparse.Namespace(checkpoint=str(src), data=str(tiny_dataset()), out=str(out), max_train=100,
                              partial=0.5, epochs=3, members=2, seed=0, threads=1, family_folds=3,
                              feature_dropout=0.5)
    assert topple_fit.run(args) == 0
    return src, out


@pytest.fixture(scope="module")
def calm(fitted):
    """`fitted` with its calibration shifted down by 1.5 on the logit: the tiny head (100 pushes of a random-weight
    model) has no sense of scale, and the rules' tests need pushes of a tall box on both sides of 0.5."""
    from physdyn_ros.learn.checkpoint import load_model, save_checkpoint

    model, ckpt = load_model(fitted[1])
    model.topple.calibration[1] -= 1.5
    out = fitted[1].with_name("calm.pt")
    save_checkpoint(out, model=model.eval(), config=ckpt["config"], dataset=ckpt.get("dataset", {}), progress=None,
                    include_rng=False)
    return fitted[0], out


def test_fit_topple_calibrates_the_head_on_families_it_left_out(fitted):
    """--family-folds: every training push is predicted by a head fitted without its family; the Platt scaling
    of those predictions is the head's calibration, stored with it and reported in the checkpoint."""
    from physdyn_ros.learn.checkpoint import load_model

    model, ckpt = load_model(fitted[1])
    fit = ckpt["config"]["topple_fit"]
    assert fit["family_folds"] == 3
    cal = fit["validation"]["calibration"]
    assert model.topple.calibration.tolist() == pytest.approx(cal, abs=1e-4)
    assert cal != [1.0, 0.0]
    for key in ("out_of_family_raw", "out_of_family"):
        assert fit["validation"][key]["n"] == fit["validation"]["train_pushes"]  # every training push, once
    by_family = fit["validation"]["out_of_family_by_family"]
    assert sorted(by_family) == ["bottle", "box", "cylinder"]  # the tiny dataset's families, each left out once
    assert sum(v["n"] for v in by_family.values()) == fit["validation"]["train_pushes"]
    assert sum(v["toppled"] for v in by_family.values()) == fit["validation"]["out_of_family"]["toppled"]


def test_platt_scaling_recovers_a_known_miscalibration():
    from physdyn_ros.learn.topple_fit import fit_calibration

    rng = np.random.default_rng(0)
    z = rng.normal(0.0, 2.0, 20000)
    y = rng.random(len(z)) < 1.0 / (1.0 + np.exp(-(0.6 * z + 0.8)))  # true: under-confident, shifted
    a, b = fit_calibration(1.0 / (1.0 + np.exp(-z)), y)
    assert a == pytest.approx(0.6, abs=0.05) and b == pytest.approx(0.8, abs=0.08)
    with pytest.raises(ValueError, match="toppled and pushes that did not"):
        fit_calibration(np.full(10, 0.3), np.zeros(10))


def test_family_folds_partition_the_families():
    from physdyn_ros.learn.topple_fit import split_families

    cats = np.array(["box", "mug", "box", "vase", "rock", "gear", "mug"])
    folds = split_families(cats, 2, seed=1)
    assert sorted(sum(folds, [])) == ["box", "gear", "mug", "rock", "vase"] and all(folds)
    with pytest.raises(ValueError, match="family folds must be in 2..5"):
        split_families(cats, 6)


def test_a_head_fitted_on_other_descriptors_is_refused_with_the_refit_command(fitted):
    from physdyn_ros.learn.checkpoint import CheckpointError, build_model, load_checkpoint

    ckpt = load_checkpoint(fitted[1])
    in_dim = build_model(ckpt).topple.in_dim
    for key in [k for k in ckpt["model"] if k.startswith("topple.")]:
        value = ckpt["model"][key]
        if value.ndim and value.shape[0] == in_dim:  # a head fitted on 3 inputs fewer
            ckpt["model"][key] = value[:-3]
    with pytest.raises(CheckpointError, match="refit the head: physdyn fit-topple"):
        build_model(ckpt, "old.pt")


def test_a_head_saved_before_the_calibration_loads_with_the_identity(fitted):
    """Checkpoints written before the calibration existed (the state dict lacks it) load and predict as before."""
    from physdyn_ros.learn.checkpoint import load_model

    model, _ = load_model(fitted[1])
    head = model.topple
    state = {k: v for k, v in head.state_dict().items() if k != "calibration"}
    head.calibration.copy_(torch.tensor([0.5, 0.5]))
    head.load_state_dict(state)
    assert head.calibration.tolist() == [1.0, 0.0]
    p = torch.tensor([0.0, 0.2, 1.0])
    assert torch.equal(head.calibrated(p), p)  # the identity leaves probabilities bit for bit


def test_fit_topple_writes_a_checkpoint_that_the_predictor_applies(calm):
    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.predictor import Predictor

    src, out = calm
    model, ckpt = load_model(out)
    assert model.topple is not None and len(model.topple.members) == 2
    assert "topple_inputs" not in ckpt["config"]["model"]
    assert ckpt["config"]["topple_fit"]["feature_dropout"] == 0.5
    assert ckpt["config"]["topple_fit"]["validation"]["n"] > 0
    assert torch.all(model.topple.std > 0)  # the input standardisation was set from the data
    plain, headed = Predictor.load(src), Predictor.load(out)
    assert headed.feature_dim == plain.feature_dim + DESCRIPTOR_DIM
    assert headed.model_id != plain.model_id
    rng = np.random.default_rng(3)
    cloud = _surface(trimesh.creation.box(extents=(0.08, 0.06, 0.2))) + [0.3, 0.1, 0.1]
    code = headed.encode(cloud)
    v = np.c_[rng.uniform(-2, 2, (64, 2)), np.zeros(64)]
    w = rng.normal(size=(64, 3)) * 2
    batch = headed.rollout_batch(code, v, w, 60)  # the head's probability is reached over the full run
    # the head's probability, straight from the model, is the trajectory's unless a pose tilts past 45 deg
    dyn = code.feature[:headed._dynamics_dim]
    heading = code.heading
    vc, wc = geo.rotate_yaw(v, -heading), geo.rotate_yaw(w, -heading)
    head, novelty = model.topple.assess(np.tile(dyn, (64, 1)), np.tile(code.feature[headed._dynamics_dim:], (64, 1)),
                                        vc, wc)
    assert np.allclose(batch.novelty, novelty) and np.all(novelty > 0)
    assert headed.rollout(code, v[0], w[0], 30).novelty == pytest.approx(novelty[0])
    assert math.isnan(plain.rollout(cloud, v[0], w[0], 30).novelty)
    tilted = rules.tilted_past(batch.orientations).any(axis=1)
    assert np.allclose(batch.topple_probability[~tilted], head[~tilted], atol=1e-6)
    assert np.all(batch.topple_probability[tilted] == 1.0)
    # consistency: no topple predicted -> the object stays on its base (yaw only)
    calm = batch.topple_probability <= 0.5
    assert calm.any()
    assert geo.up_tilt_angle(batch.orientations[calm]).max() < 1e-6
    # the dynamics network sees only its own part of the feature: positions match the plain model's where both
    # let the object tilt the same way (no tilt from either)
    base = plain.rollout_batch(plain.encode(cloud), v, w, 60)
    same = calm & (base.topple_probability <= 0.5)
    if same.any():
        assert np.abs(base.positions[same] - batch.positions[same]).max() < 1e-6


def test_the_predictor_rests_a_view_on_the_table_of_its_frame(fitted):
    """A camera 60 deg above a ball on the table sees down to a quarter of its height: the topple head's centre
    of mass height counts from the table (z = 0 of the table frame), not from the lowest point seen. The same
    view 0.5 m above the table (a cloud given in another frame) counts from its lowest point."""
    from physdyn_ros.learn.support import DESCRIPTOR_POINTS
    from physdyn_ros.predictor import Predictor

    pred = Predictor.load(fitted[1])
    ball = _surface(trimesh.creation.icosphere(subdivisions=4, radius=0.05), 6000) + [0.3, 0.1, 0.05]
    view = _view(ball, 30.0, 60.0)
    low = float(view[pred._subset(len(view), DESCRIPTOR_POINTS), 2].min())  # of the points the head reads
    assert 0.015 < low < 0.045  # the lowest point seen is cm above the table
    on_table, lifted = pred.encode(view), pred.encode(view + [0.0, 0.0, 0.5])
    h = pred._dynamics_dim  # descriptor 0: the centre of mass's height over the support
    assert on_table.feature[h] - lifted.feature[h] == pytest.approx(low, abs=1e-5)
    assert np.array_equal(on_table.feature[:h], lifted.feature[:h])  # the learned feature does not move


def test_the_predictor_counts_the_support_from_the_plane_perception_found(fitted):
    """The perception node fits the table plane (up to plane_max_offset off z = 0) and removes the points within
    5 mm of it; it passes the plane's height under each object to encode_many. A box on a plane 8 mm up, its
    bottom 5 mm removed, keeps its support polygon that way; taken on z = 0 its lowest point lies 1.3 cm up, an
    unseen support (the foot alone)."""
    from physdyn_ros.predictor import Predictor

    pred = Predictor.load(fitted[1])
    h = pred._dynamics_dim
    box = trimesh.creation.box(extents=(0.1, 0.06, 0.1))
    pts = np.concatenate([_surface(box, 6000), np.asarray(box.vertices)]) + [0.2, 0.1, 0.05 + 0.008]
    cut = pts[pts[:, 2] > 0.008 + 0.005]
    whole, on_plane = pred.encode(pts, 0.008), pred.encode(cut, table_height=0.008)
    on_zero = pred.encode(cut)
    area = h + 2
    assert whole.feature[area] > 0.004 and on_plane.feature[area] == pytest.approx(whole.feature[area], rel=0.2)
    assert on_zero.feature[area] < 1e-4
    assert on_zero.feature[h] - on_plane.feature[h] == pytest.approx(0.008, abs=1e-6)  # heights from the plane
    with pytest.raises(ValueError, match="table_heights must be one finite height"):
        pred.encode_many([pts, cut], [0.0])
    with pytest.raises(ValueError, match="table_heights must be one finite height"):
        pred.encode(pts, float("nan"))


def test_the_head_keeps_the_predictor_equivariant_to_yaw(fitted):
    from physdyn_ros.predictor import Predictor

    pred = Predictor.load(fitted[1])
    cloud = _surface(trimesh.creation.box(extents=(0.1, 0.05, 0.15))) + [0.0, 0.0, 0.075]
    v, w, psi = np.array([0.8, 0.3, 0.0]), np.array([0.5, -1.0, 3.0]), 0.9
    a = pred.rollout(cloud, v, w, 30)
    b = pred.rollout(geo.rotate_yaw(cloud, psi), geo.rotate_yaw(v, psi), geo.rotate_yaw(w, psi), 30)
    assert abs(a.topple_probability - b.topple_probability) < 1e-4
    assert np.abs(geo.rotate_yaw(a.positions, psi) - b.positions).max() < 1e-4


def test_training_windows_carry_the_table_the_predictor_reads():
    """fit-topple and evaluation take the table's height in frame C from the simulation (make_windows "table");
    the Predictor from the cloud's frame (z = 0 of the table frame): both give the same height for the same
    posed cloud, and a whole cloud at the push instant rests on it (its lowest point within 1 cm above)."""
    from physdyn_ros.learn import frames
    from physdyn_ros.learn.windows import load_sims, make_windows

    sims = load_sims(tiny_dataset(), ["train"])
    index = np.arange(min(30, len(sims)))
    n = sims.points.shape[1]
    seq = make_windows(sims, index, np.zeros(len(index), dtype=np.int64), 2, n)
    table = seq["table"].numpy()
    gap = seq["cloud"].numpy()[:, :, 2].min(axis=1) - table
    assert np.all(gap > -1e-4) and np.all(gap < 0.01), gap
    world = frames.pose_cloud(sims.points[sims.shape_index[index]], sims.scale[index], sims.quat[index, 0])
    world = world + sims.pos[index, 0][:, None, :]  # the cloud in the table frame, as perception gives it
    as_predictor = -frames.canonicalize_cloud(world).centroid[:, 2]
    assert np.allclose(as_predictor, table, atol=1e-5)
    later = make_windows(sims, index, np.full(len(index), 5), 2, n)  # mid-motion: above the table, up to the
    assert np.all(later["cloud"].numpy()[:, :, 2].min(axis=1) - later["table"].numpy() > -0.005)  # contacts' mm


def test_evaluation_sees_clouds_as_the_perception_node_delivers_them():
    """`physdyn evaluate --plane-gap 0.005`: the points within 5 mm of the table are removed from the model's
    clouds (the perception node's plane_distance), full clouds and views alike; 0 changes nothing."""
    from physdyn_ros.learn.windows import load_sims, sequences

    sims = load_sims(tiny_dataset(), ["test"])
    index = np.arange(min(20, len(sims)))
    plain = sequences(sims, 1, 256, index, 0.5, 0.002, view_seed=3)
    same = sequences(sims, 1, 256, index, 0.5, 0.002, view_seed=3, plane_gap=0.0)
    assert torch.equal(plain["cloud"], same["cloud"])
    cut = sequences(sims, 1, 256, index, 0.5, 0.002, view_seed=3, plane_gap=0.005)
    low = cut["cloud"][:, :, 2].min(dim=1).values - cut["table"]
    assert cut["cloud"].shape == plain["cloud"].shape and bool(torch.all(low > 0.005 - 1e-6))
    assert bool(torch.all(plain["cloud"][:, :, 2].min(dim=1).values - plain["table"] < 0.005))


def test_evaluation_applies_the_head_as_the_predictor_does(fitted):
    """physdyn evaluate's roll-outs carry the head's probabilities (same rule as the Predictor)."""
    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.evaluate import model_rollouts
    from physdyn_ros.learn.topple_fit import topple_inputs
    from physdyn_ros.learn.windows import load_sims

    model, _ = load_model(fitted[1])
    sims = load_sims(tiny_dataset(), ["test"])
    index = np.arange(min(20, len(sims)))
    traj = model_rollouts(model, sims, index, 60)
    data = topple_inputs(model, sims, index, 0.0)
    with torch.inference_mode():
        head = model.topple(*(torch.from_numpy(data[k]).float() for k in ("feature", "desc", "push"))).numpy()
    tilted = rules.tilted_past(traj.quat).any(axis=1)
    assert np.allclose(traj.topple_prob.max(axis=1)[~tilted], head[~tilted], atol=1e-5)


def test_training_pushes_are_dealt_over_datasets_in_proportion():
    from physdyn_ros.learn.topple_fit import _shares

    assert _shares([300], 100) == [100] and _shares([80], 100) == [80]
    assert _shares([300, 100], 100) == [75, 25]
    assert _shares([2, 1, 1], 3) == [1, 1, 1] and _shares([5, 3, 2], 7) == [4, 2, 1]
    assert _shares([50, 30], 1000) == [50, 30]  # never more than a dataset holds


def test_a_dataset_whose_share_rounds_to_nothing_is_skipped(fitted):
    """Review finding: a small dataset next to a large one got a share of 0 pushes and the fit failed joining
    nothing; it is now skipped."""
    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.topple_fit import _shares, fit_topple_head
    from physdyn_ros.learn.windows import load_sims

    assert _shares([10000, 3], 100) == [100, 0]
    model, _ = load_model(fitted[1])
    train, val = load_sims(tiny_dataset(), ["train"]), load_sims(tiny_dataset(), ["val"])
    small = train.subset([0])
    assert _shares([len(train), 1], 20) == [20, 0]
    result = fit_topple_head(model, [train, small], [val], max_train=20, epochs=1, family_folds=0, log=None)
    assert result["train_pushes"] == 20


def test_fit_topple_draws_from_several_datasets_and_takes_whole_or_partial_views_only(tmp_path):
    """--data repeated: the training pushes come from every dataset (here the tiny one twice: more pushes than
    one holds), each dataset recorded; --partial 0 or 1 (one kind of cloud only) fits instead of failing on an
    empty set of views."""
    from physdyn_ros.learn import topple_fit
    from physdyn_ros.learn.checkpoint import load_checkpoint
    from physdyn_ros.learn.windows import load_sims

    one = len(load_sims(tiny_dataset(), ["train"]))
    src = random_checkpoint(tmp_path / "src.pt")
    for partial in (0.0, 1.0):
        out = tmp_path / f"two{partial}.pt"
        args = argparse.Namespace(checkpoint=str(src), data=[str(tiny_dataset())] * 2, out=str(out),
                                  max_train=2 * one, partial=partial, epochs=1, members=1, seed=0, threads=1,
                                  family_folds=0, feature_dropout=0.5)
        assert topple_fit.run(args) == 0
        fit = load_checkpoint(out)["config"]["topple_fit"]
        assert fit["validation"]["train_pushes"] == 2 * one
        assert fit["data"] == [str(tiny_dataset().resolve())] * 2


def test_fit_topple_refuses_bad_arguments(tmp_path):
    from physdyn_ros.learn import topple_fit

    args = argparse.Namespace(checkpoint=str(random_checkpoint(tmp_path / "m.pt")), data=str(tiny_dataset()),
                              out=str(tmp_path / "o.pt"), max_train=10, partial=0.5, epochs=1, members=1, seed=0,
                              threads=1)
    with pytest.raises(ValueError, match="--max-train"):
        topple_fit.run(args)
    assert not (tmp_path / "o.pt").exists()


def test_novelty_flags_inputs_unlike_the_training_data(fitted):
    """Novelty 1 is the 99.5th percentile of the training inputs' distance or the edge of their range: most
    training pushes lie below it; a push far faster and a shape far flatter than any in the tiny dataset above."""
    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.topple_fit import topple_inputs
    from physdyn_ros.learn.windows import load_sims
    from physdyn_ros.predictor import Predictor

    model, _ = load_model(fitted[1])
    sims = load_sims(tiny_dataset(), ["train"])
    data = topple_inputs(model, sims, np.arange(len(sims)), 0.0)
    with torch.inference_mode():
        x = model.topple.raw_inputs(*(torch.from_numpy(data[k]).float() for k in ("feature", "desc", "push")))
        novelty = model.topple.novelty(x).numpy()
    assert np.median(novelty) < 1.0  # (the tiny fit saw 100 pushes, half of them partial views)
    pred = Predictor.load(fitted[1])
    box = _surface(trimesh.creation.box(extents=(0.06, 0.06, 0.12))) + [0, 0, 0.06]
    assert pred.rollout(box, [9.0, 0.0, 0.0], [0.0, 0.0, 60.0], 20).novelty > 1.0
    plate = _surface(trimesh.creation.box(extents=(0.4, 0.4, 0.004))) + [0, 0, 0.005]
    assert pred.rollout(plate, [0.5, 0.0, 0.0], [0.0, 0.0, 1.0], 20).novelty > 1.0


def test_numpy_inference_equals_the_torch_head(fitted):
    """assess (numpy, what the Predictor runs) gives the torch module's probability and novelty."""
    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.topple_fit import topple_inputs
    from physdyn_ros.learn.windows import load_sims

    model, _ = load_model(fitted[1])
    sims = load_sims(tiny_dataset(), ["test"])
    d = topple_inputs(model, sims, np.arange(min(40, len(sims))), 0.5)
    vel, angvel = d["push"][:, :3], d["push"][:, 3:6]
    prob, novelty = model.topple.assess(d["feature"], d["desc"], vel, angvel)
    with torch.no_grad():
        args = [torch.from_numpy(d[k]).double() for k in ("feature", "desc", "push")]
        head = model.topple.double()
        want = head(*args).numpy()
        want_novelty = head.novelty(head.raw_inputs(*args)).numpy()
    assert np.allclose(prob, want, atol=1e-9) and np.allclose(novelty, want_novelty, rtol=1e-6)
    with torch.no_grad():  # a changed weight is seen (the numpy copy is rebuilt)
        model.topple.members[0][4].bias += 5.0
    assert np.all(model.topple.assess(d["feature"], d["desc"], vel, angvel)[0] > prob)


def _tall_box_pushes(fitted, seed: int):
    """(predictor, code, v, w, 60-step batch) of 32 random pushes of a 5 x 5 x 20 cm box with the fitted head."""
    from physdyn_ros.predictor import Predictor

    pred = Predictor.load(fitted[1])
    code = pred.encode(_surface(trimesh.creation.box(extents=(0.05, 0.05, 0.2))) + [0.0, 0.0, 0.1])
    rng = np.random.default_rng(seed)
    v = np.c_[rng.uniform(-2, 2, (32, 2)), np.zeros(32)]
    w = rng.normal(size=(32, 3))
    return pred, code, v, w, pred.rollout_batch(code, v, w, 60)


def test_a_short_horizon_is_the_prefix_of_the_full_roll_out(fitted):
    """The head's whole-push probability is not squeezed into the requested horizon (horizon 1 would read
    'toppled by 67 ms' with the head's probability): a short roll-out is the prefix of the 60-step one."""
    pred, code, v, w, full = _tall_box_pushes(fitted, seed=8)
    for h in (1, 5, 30):
        short = pred.rollout_batch(code, v, w, h)
        assert short.positions.shape[1] == h + 1
        for name in ("positions", "orientations", "lin_vels", "ang_vels", "topple_prob"):
            assert np.allclose(getattr(short, name), getattr(full, name)[:, :h + 1], atol=1e-9), (h, name)


def test_a_planner_roll_out_ends_at_the_whole_push_probability(calm):
    """head_timing=False (the planner's search): only `horizon` steps are rolled out and their maximum is the
    head's whole-push probability (a push that topples after the search horizon still counts); the motion is
    the full roll-out's prefix."""
    pred, code, v, w, full = _tall_box_pushes(calm, seed=9)
    short = pred.rollout_batch(code, v, w, 12, head_timing=False)
    assert short.positions.shape[1] == 13
    calm = full.topple_probability <= 0.5  # no tilt either way: the same motion
    assert np.abs(short.positions[calm] - full.positions[calm, :13]).max() < 1e-9
    assert np.allclose(short.topple_probability[calm], full.topple_probability[calm], atol=1e-9)
    assert np.all(short.topple_prob[calm, :13].max(axis=1) >= full.topple_prob[calm, :13].max(axis=1) - 1e-12)


def test_a_model_with_a_fitted_head_can_be_fine_tuned(fitted, tmp_path, capsys):
    """`physdyn train --init` the shipped kind of checkpoint (a fitted head, its topple_fit record): it failed
    with "unknown config sections ['topple_fit']". The fine-tune starts from the dynamics weights and drops the
    head, whose inputs the fine-tune changes (refit it with fit-topple)."""
    from physdyn_ros.cli import main
    from physdyn_ros.learn.checkpoint import load_checkpoint, load_model

    out = tmp_path / "ft"
    code = main(["train", "--init", str(fitted[1]), "--data", str(tiny_dataset()), "--out", str(out),
                 "--max-epochs", "1", "--set", "train.lr=1e-9", "--set", "train.lr_min=1e-9", "--seed", "7",
                 "--no-progress"])
    assert code == 0, capsys.readouterr().err[-2000:]
    model, ckpt = load_model(out / "model_best.pt")
    assert model.topple is None and "topple_fit" not in ckpt["config"]
    before = load_checkpoint(fitted[1])["model"]
    after = ckpt["model"]
    assert not any(k.startswith("topple.") for k in after)
    for k, w in after.items():  # the dynamics weights are the init's (a negligible learning rate; another seed
        assert torch.allclose(w.float(), before[k].float(), atol=1e-5), k  # than the init's, so not a fresh init)


def test_dense_descriptors_come_from_the_same_cloud_in_the_same_frame():
    """desc_points: a fixed subset of the same (posed, viewed) cloud in the same frame C; the encoder's cloud is
    unchanged by asking for it, and holds a subset of its points when it asks for all of them."""
    from physdyn_ros.learn.windows import load_sims, sequences

    sims = load_sims(tiny_dataset(), ["test"])
    index = np.arange(min(12, len(sims)))
    plain = sequences(sims, 1, 128, index, 0.5, 0.002, view_seed=5)
    dense = sequences(sims, 1, 128, index, 0.5, 0.002, view_seed=5, desc_points=sims.points.shape[1])
    assert "desc_cloud" not in plain and dense["desc_cloud"].shape == (len(index), sims.points.shape[1], 3)
    assert torch.equal(plain["cloud"], dense["cloud"]) and torch.equal(plain["heading"], dense["heading"])
    gap = torch.cdist(dense["cloud"].double(), dense["desc_cloud"].double()).min(dim=2).values
    assert float(gap.max()) < 1e-6


def test_a_dense_head_reads_the_same_descriptors_in_the_predictor_as_in_training(fitted):
    """The head's descriptors come from DESCRIPTOR_POINTS points of the cloud (evaluation reads what training
    reads: test_evaluation_applies_the_head_as_the_predictor_does, on the same head)."""
    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.support import DESCRIPTOR_POINTS
    from physdyn_ros.learn.topple_fit import topple_inputs
    from physdyn_ros.learn.windows import load_sims
    from physdyn_ros.predictor import Predictor

    model, ckpt = load_model(fitted[1])
    assert DESCRIPTOR_POINTS == 1024 > model.cfg.num_points
    sims = load_sims(tiny_dataset(), ["test"])
    index = np.arange(min(20, len(sims)))
    data = topple_inputs(model, sims, index, 0.0)
    # the Predictor, given a simulation's cloud where it stands, reads the descriptors training read (1024
    # points), not those of the encoder's 128
    from physdyn_ros.learn import frames

    pred = Predictor.load(fitted[1])
    for i in index[:4]:
        world = frames.pose_cloud(sims.points[sims.shape_index[i]], sims.scale[i], sims.quat[i, 0]) + sims.pos[i, 0]
        desc = pred.encode(world, table_height=0.0).feature[pred._dynamics_dim:]
        assert np.allclose(desc, data["desc"][i], rtol=1e-5, atol=1e-6)
        sparse = pred.encode(world[pred._subset(len(world))]).feature[pred._dynamics_dim:]
        assert not np.allclose(sparse, data["desc"][i], rtol=1e-4, atol=1e-5)
