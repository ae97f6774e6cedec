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
"""Partial views: the z-buffer hides the far side and the bottom; sampling stays within the visible points."""
from __future__ import annotations

import numpy as np

from physdyn_ros.learn.views import random_view_dirs, sample_visible, visible
from physdyn_ros.shapes import generate_shapes


def test_a_box_seen_from_above_and_one_side_shows_two_faces_not_the_others():
    shape = generate_shapes("box", 1, seed=1)[0]
    pts = shape.points.astype(np.float64)
    half = 0.5 * (pts.max(0) - pts.min(0))
    d = np.array([[1.0, 0.0, 1.0]]) / np.sqrt(2)  # from +x and above
    seen = visible(pts[None], d)[0]
    on = {name: np.abs(pts[:, a] - s * half[a]) < 1e-6 for name, a, s in
          (("+x", 0, 1), ("-x", 0, -1), ("+z", 2, 1), ("-z", 2, -1))}
    assert seen[on["+x"]].mean() > 0.9 and seen[on["+z"]].mean() > 0.9
    assert seen[on["-x"]].mean() < 0.2 and seen[on["-z"]].mean() < 0.2  # silhouette edges leak a little
    # what is seen is biased to the camera: its centroid lies off the centre of mass (the origin)
    assert pts[seen].mean(0)[0] > 0.2 * half[0]


def test_sampling_only_returns_visible_points():
    rng = np.random.default_rng(0)
    shapes = generate_shapes("mug", 4, seed=0)
    pts = np.stack([s.points for s in shapes]).astype(np.float64)
    dirs = random_view_dirs(4, rng)
    mask = visible(pts, dirs)
    assert np.all(mask.mean(1) > 0.15) and np.all(mask.mean(1) < 0.8)
    idx = sample_visible(mask, 256, rng)
    assert idx.shape == (4, 256) and np.take_along_axis(mask, idx, 1).all()
    one = np.zeros((1, 10), dtype=bool)
    one[0, 3] = True
    assert set(sample_visible(one, 5, rng)[0]) == {3}


def test_partial_windows_hide_the_centre_of_mass_from_the_centroid():
    """Windows seen as partial views: the COM target is off the centroid by cm, and the same seed gives the
    same views (evaluation is reproducible)."""
    from learn_support import tiny_dataset
    from physdyn_ros.learn.windows import load_sims, sequences

    sims = load_sims(tiny_dataset(), ("train",))
    full = sequences(sims, 10, 64)
    part = sequences(sims, 10, 64, partial=1.0, noise=0.002, view_seed=3)
    again = sequences(sims, 10, 64, partial=1.0, noise=0.002, view_seed=3)
    assert np.allclose(part["cloud"].numpy(), again["cloud"].numpy())
    off_full = np.linalg.norm(full["com"].numpy(), axis=-1)
    off_part = np.linalg.norm(part["com"].numpy(), axis=-1)
    assert np.median(off_part) > np.median(off_full) + 0.005  # a one-sided view moves the centroid by cm
    # the motion is the same; only frame C turns with the heading of what is seen
    assert np.allclose(np.linalg.norm(part["d_pos"].numpy(), axis=-1), np.linalg.norm(full["d_pos"].numpy(), axis=-1),
                       atol=1e-6)
