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
"""Ids through fast pushes and absences: tracking.Tracker's second chance by shape signature."""
from __future__ import annotations

import numpy as np

from physdyn_ros.perception import SceneConfig, Tracker, segment
from physdyn_ros.perception.synthetic import DEFAULT_OBJECTS, tabletop_scene
from physdyn_ros.perception.tracking import shape_signature


def detect(specs, seed: int):
    scene = tabletop_scene(20_000, objects=specs, rng=np.random.default_rng(seed))
    objs = segment(scene.points, SceneConfig(), scene.camera, np.random.default_rng(seed)).objects
    return [o.centroid for o in objs], [shape_signature(o.points) for o in objs]


def ids_by_object(tracker: Tracker, specs, t: float, seed: int) -> list[str]:
    """The id given to each of `specs` (nearest detection)."""
    cents, sigs = detect(specs, seed)
    ids = tracker.update(cents, t, sigs)
    return [ids[int(np.argmin([np.hypot(*(c[:2] - [s.x, s.y])) for c in cents]))] for s in specs]


def test_a_20_cm_jump_between_clouds_keeps_the_id_and_nobody_swaps():
    tracker = Tracker()
    specs = list(DEFAULT_OBJECTS)
    first = ids_by_object(tracker, specs, 0.0, 0)
    assert sorted(first) == ["object_1", "object_2", "object_3"]
    specs[0] = specs[0].moved(dx=0.07, dy=-0.19, dyaw=0.8)  # 20 cm and 46 deg in one interval (5 Hz, 1 m/s)
    assert ids_by_object(tracker, specs, 0.2, 1) == first
    assert ids_by_object(tracker, specs, 0.4, 2) == first


def test_an_object_that_leaves_and_returns_is_matched_by_shape():
    tracker = Tracker(timeout=2.0)
    specs = list(DEFAULT_OBJECTS)
    first = ids_by_object(tracker, specs, 0.0, 0)
    away = specs[1:]
    assert ids_by_object(tracker, away, 1.0, 1) == first[1:]  # object 0 out of view for a second
    back = [specs[0].moved(dx=0.25, dy=0.1, dyaw=1.2)] + away  # ... and back, 27 cm away, turned
    assert ids_by_object(tracker, back, 1.5, 2) == first
    # another shape where it was is not given its id
    tracker = Tracker()
    first = ids_by_object(tracker, specs, 0.0, 0)
    ids_by_object(tracker, away, 1.0, 1)
    other = [type(specs[0])("cylinder", specs[0].x + 0.2, specs[0].y, 0.0, (0.02, 0.02, 0.09))] + away
    got = ids_by_object(tracker, other, 1.5, 2)
    assert got[1:] == first[1:] and got[0] not in first


def test_an_object_hidden_past_the_timeout_gets_its_id_back_by_shape():
    """Past track_timeout an unseen object is lost, not forgotten: within `memory` its id goes to the next object
    of its shape near where it was (hidden behind another for 3 s), never to another shape; after `memory` the
    id is retired for good."""
    specs = list(DEFAULT_OBJECTS)
    tracker = Tracker(timeout=1.0, memory=10.0)
    first = ids_by_object(tracker, specs, 0.0, 0)
    for k, t in enumerate((1.0, 2.0, 3.0)):  # object 0 hidden for 3 s
        assert ids_by_object(tracker, specs[1:], t, k + 1) == first[1:]
    assert [i for i, _ in tracker.take_losses()] == [first[0]] and not tracker.take_retired()
    assert ids_by_object(tracker, specs, 3.5, 4) == first
    # another shape where a lost object was does not get its id
    tracker = Tracker(timeout=1.0, memory=10.0)
    first = ids_by_object(tracker, specs, 0.0, 0)
    ids_by_object(tracker, specs[1:], 2.0, 1)
    other = [type(specs[0])("cylinder", specs[0].x, specs[0].y, 0.0, (0.02, 0.02, 0.09))] + specs[1:]
    got = ids_by_object(tracker, other, 2.5, 2)
    assert got[1:] == first[1:] and got[0] not in first
    # past memory the id is retired: the object comes back under a new one
    tracker = Tracker(timeout=1.0, memory=3.0)
    first = ids_by_object(tracker, specs, 0.0, 0)
    ids_by_object(tracker, specs[1:], 2.0, 1)
    ids_by_object(tracker, specs[1:], 4.0, 2)
    assert [i for i, _ in tracker.take_retired()] == [first[0]]
    got = ids_by_object(tracker, specs, 4.5, 3)
    assert got[1:] == first[1:] and got[0] not in first


def test_an_object_whose_cloud_splits_for_one_frame_keeps_its_id():
    """A sparse object's cluster that splits in two for one cloud starts a young track on one half; when the
    object is whole again, nearer that young track's last centroid than its own track's, it keeps its old id."""
    tracker = Tracker()
    obj, other = np.array([0.0, 0.0, 0.04]), np.array([0.3, 0.0, 0.04])
    for k in range(20):
        assert tracker.update([obj, other], k / 15) == ["object_1", "object_2"]
    halves = tracker.update([obj + [0.02, 0, 0], obj - [0.035, 0, 0], other], 20 / 15)
    assert halves == ["object_1", "object_3", "object_2"]
    assert tracker.update([obj - [0.01, 0, 0], other], 21 / 15) == ["object_1", "object_2"]
    # the half's track is a second track on object_1's object: dropped, not left to take the object later
    assert sorted(tr.id for tr in tracker.tracks) == ["object_1", "object_2"]
    assert tracker.take_retired() == [("object_3", "a second track on the object of object_1")]


def test_a_fragment_of_an_object_keeps_the_id_without_dragging_the_track_off():
    """Under depth noise a long box's cluster kept only one end for a cloud, twice, each time farther off (seen in
    bench_tracking's noisy clouds), the second beyond the gate: both get the box's id, but the track holds its
    centroid, velocity and signature, so the whole box on the next cloud keeps its id (before, the track followed
    the fragments beyond the gate, its signature drifted past the second chance's tolerance, and the box got a new
    id)."""
    tracker = Tracker()
    box, other = np.array([0.2, -0.25, 0.044]), np.array([-0.15, -0.09, 0.03])
    box_sig, other_sig = np.array([0.06, 0.016, 0.088]), np.array([0.047, 0.022, 0.035])
    for k in range(20):
        assert tracker.update([box, other], k / 15, [box_sig, other_sig]) == ["object_1", "object_2"]
    end_sig = np.array([0.015, 0.016, 0.04])  # flat and short: one end of the box's top
    near = tracker.update([box + [-0.06, 0.0, 0.016], other], 20 / 15, [end_sig, other_sig])
    assert near == ["object_1", "object_2"] and tracker.parts == [0]  # within the gate: the box's id, as a part
    # beyond the gate, but within the box (its ends lie 1.7 spreads from its middle): still the box's
    far = tracker.update([box + [-0.11, 0.0, 0.016], other], 21 / 15, [end_sig, other_sig])
    assert far == ["object_1", "object_2"] and tracker.parts == [0]
    held = next(tr for tr in tracker.tracks if tr.id == "object_1")
    state = (held.centroid.copy(), held.velocity.copy(), held.signature.copy())
    assert tracker.update([box + [0.003, 0.0, 0.0], other], 22 / 15, [box_sig, other_sig]) == ["object_1", "object_2"]
    assert tracker.parts == []
    assert np.allclose(state[0], box) and np.allclose(state[1], 0.0) and np.allclose(state[2], box_sig)
    assert tracker.count == 2  # no id for the box's end
    # something as small farther than the box reaches is not a part of it
    assert tracker.update([box + [-0.3, 0.0, 0.016], other], 23 / 15, [end_sig, other_sig]) == ["object_3", "object_2"]
    # a track still young, or detections without signatures, are followed as before
    young = Tracker()
    young.update([box], 0.0, [box_sig])
    young.update([box + [-0.06, 0.0, 0.0]], 1 / 15, [end_sig])
    assert np.allclose(young.tracks[0].centroid, box + [-0.06, 0.0, 0.0])


def test_parts_neither_keep_a_track_alive_nor_take_a_toppled_object():
    """A part stands in for its object for at most PART_HOLD s after the object's last whole view: a view that
    stays smaller is the object's new view (a wedge turned to its thin side, seen in push_to_goal) and is followed,
    with its own signature from then on. A tall box that topples is no part of itself (its height falls, but its
    x-y spread grows): the track follows it. Seen as a part, the track's constant-velocity prediction still runs
    from the last whole view."""
    box, box_sig = np.array([0.3, 0.0, 0.10]), np.array([0.20, 0.017, 0.017])  # 6 x 6 x 20 cm, standing
    tracker = Tracker(timeout=1.0)
    for k in range(20):
        tracker.update([box], k / 15, [box_sig])
    lying, lying_sig = box + [0.07, 0.0, -0.07], np.array([0.06, 0.017, 0.058])
    assert tracker.update([lying], 20 / 15, [lying_sig]) == ["object_1"] and tracker.parts == []
    assert np.allclose(tracker.tracks[0].centroid, lying)

    tracker = Tracker(timeout=1.0)
    for k in range(20):
        tracker.update([box], k / 15, [box_sig])
    top = np.array([0.04, 0.017, 0.017])  # from now on only its top is seen
    held = []
    for k in range(20, 40):
        assert tracker.update([box + [0.0, 0.0, 0.08]], k / 15, [top]) == ["object_1"]
        held.append(bool(tracker.parts))
    assert held[:4] == [True] * 4 and not any(held[5:])  # 0.3 s, then the new view is the object's
    assert np.allclose(tracker.tracks[0].signature, top) and tracker.count == 1

    moving = Tracker()
    for k in range(20):
        moving.update([box + [0.4 * k / 15, 0.0, 0.0]], k / 15, [box_sig])
    for k in range(20, 23):
        assert moving.update([box + [0.4 * k / 15, 0.0, 0.08]], k / 15, [top]) == ["object_1"]
    assert moving.update([box + [0.4 * 23 / 15, 0.0, 0.0]], 23 / 15, [box_sig]) == ["object_1"]
    assert np.allclose(moving.tracks[0].velocity, [0.4, 0.0, 0.0], atol=1e-9)


def test_single_object_mode_holds_its_track_on_a_part():
    """follow() as update(): a part of the followed object within the gate, or beyond it but inside the object, is
    returned and listed in `parts` while the track holds; a whole detection within the gate wins over a nearer
    part; the whole object on the next cloud continues the track."""
    box, box_sig = np.array([0.2, -0.25, 0.044]), np.array([0.06, 0.016, 0.088])
    end_sig = np.array([0.015, 0.016, 0.04])
    tracker = Tracker()
    for k in range(20):
        assert tracker.follow([box], k / 15, "seen", [box_sig]) == 0
    assert tracker.follow([box + [-0.11, 0.0, 0.016]], 20 / 15, "seen", [end_sig]) == 0 and tracker.parts == [0]
    assert np.allclose(tracker.tracks[0].centroid, box)
    other = box + [0.06, 0.0, 0.0]  # a whole detection within the gate, farther than the part
    assert tracker.follow([box + [-0.01, 0.0, 0.016], other], 21 / 15, "seen", [end_sig, box_sig]) == 1
    assert tracker.parts == []
    assert tracker.follow([box], 22 / 15, "seen", [box_sig]) == 0 and tracker.parts == []
    assert [tr.id for tr in tracker.tracks] == ["seen"] and not tracker.take_retired()
