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
"""A table-top cloud -> the points of each object on the table (numpy and scipy only; no ROS, no open3d).

Pipeline of `segment` (each step bounded so that a 100k-point cloud costs a few milliseconds):

1. keep finite points (column-wise tests: row reductions and boolean row masks of an (N, 3) array are ~10x
   slower in numpy); a cloud larger than `max_points` is randomly subsampled (the ROS reader already does this
   while reading, so only `max_points` points are ever copied);
2. optional crop box (table frame);
3. table plane (`remove_plane`): RANSAC on a random sample of `PLANE_SAMPLE` points, restricted to planes within
   `plane_max_tilt` of horizontal whose height at the table origin is within `plane_max_offset` of z = 0. Such a
   plane counts as the table only if part of it lies away from the objects (more than `cluster_tolerance` in
   x-y from every point above it): a plane found only under the objects is their bottom faces (a cloud of
   objects without the table, like the sim's), and is kept; and only if it cuts through no object (points just
   below it under points above it: in a cloud without the table, a plane through the objects' lower faces). The
   table's inliers and everything below it are then removed from *all* points, with the plane expressed in the
   cloud's own frame (one dot product per point, no transform of the whole cloud);
4. optional voxel grid (`voxel_size`, mean of each cell);
5. random subsample of the remaining points to `sample_points`, transformed to the table frame;
6. clusters: the sample's points are binned into cubic cells of side `cluster_tolerance`, and occupied cells
   that touch (26-neighbourhood) form one cluster. Surfaces closer than `cluster_tolerance` are always joined;
   surfaces farther apart than 2 * sqrt(3) = 3.5 cell sides are never joined (so objects closer than about
   3.5 * cluster_tolerance may merge into one). When the sample is too sparse for its cells to touch (fewer
   than 1.5 points per occupied cell on average: a large object, few sample points) the cell grows by 1.5x, up
   to 4 * cluster_tolerance. Clusters of fewer than `min_points` points are noise; clusters wider than
   `cluster_max_size` along any axis are not tabletop objects (typically the table itself when the plane was
   not removed); the largest `max_objects` remaining clusters are the objects;
7. per object: a random subsample of at most `object_points` points, then statistical outlier removal
   (`outlier_neighbors`, `outlier_std_ratio`: drop points whose mean distance to their k nearest neighbours is
   above the mean of those distances + ratio * their standard deviation); at least `min_points` must remain;
8. an object whose lowest point lies more than FLOAT_HEIGHT above the table (its plane, else z = 0 of the table
   frame) rests on something: where its x-y outline covers the points of a lower object at least FLOAT_HEIGHT
   tall that reaches up to within FLOAT_GAP of it (or that object's outline covers its points) by FLOAT_OVERLAP,
   the two are one object. A camera above a pedestal, a stool or a table sees the rim of the top and the stem or
   legs below, but not where they join.

The k-nearest-neighbour queries run on at most `object_points` points per object: a k-d tree query over the
whole scene cost 14-27 ms alone on the 2-core test machine, more than the budget for the whole cloud.
`Scene.surface` (the dense points of one object, for a new pose track's reference) is the exception, called once
per new track: it transforms the points of steps 1-4 and queries those in the object's bounding box.

All randomness comes from the generator passed in (seeded by the caller): results are reproducible.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .frames import RigidTransform

#: Points of the RANSAC sample (the plane is then applied to every point).
PLANE_SAMPLE = 1024
#: RANSAC hypotheses (vectorised: all scored at once).
PLANE_ITERATIONS = 50
#: m beyond plane_max_offset + plane_distance: the height band the RANSAC hypotheses are drawn from.
BAND_MARGIN = 0.02
#: A plane is the table only if at least this share of its sampled inliers lies away from the objects ...
TABLE_FREE_SHARE = 0.1
#: ... and it cuts through no object: at most this share of its inliers' x-y cells also hold points above it and
#: points just below it (within plane_max_offset + BAND_MARGIN; a floor lies deeper). A table's area is mostly
#: free of both; a plane through the lower faces of objects in a table-less cloud has its inliers on those faces.
TABLE_CUT_SHARE = 0.1
#: ... and, where more than this share of the sample lies just below it (a table's depth noise, a lower surface
#: beside it, objects standing through it) ...
TABLE_BELOW_SHARE = 0.04
#: ... at most this share (and 3 points) lies below points more than twice plane_distance above it (in the same
#: x-y cell or the 8 around it: clear of the table's noise). What a camera sees below a table is its edge, a wall's
#: foot, mixed pixels; objects that stand through a plane make it the flat top of a large object (a ring, a tray)
#: in a cloud without the table, which the cell share above misses when the plane's own area is large.
TABLE_THROUGH_SHARE = 0.01
#: Points farther than this from the table frame's origin (m, any axis) are not used: not a tabletop, and it keeps
#: the cell keys of the clustering within int64 (1e30 garbage values).
MAX_COORD = 100.0
#: m above the table plane: an object whose lowest point lies higher is held up by something (step 8) ...
FLOAT_HEIGHT = 0.02
#: ... and joins the object whose points its x-y outline covers by this share (or that covers its points so) ...
FLOAT_OVERLAP = 0.5
#: ... if that object reaches up to within this (m) of its lowest point: a hand above an object is no part of it.
FLOAT_GAP = 0.05
#: The 13 neighbour offsets of a cell that come after it (the other 13 are their opposites).
_HALF_OFFSETS = [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
                 if (dx, dy, dz) > (0, 0, 0)]


@dataclass
class SceneConfig:
    """Segmentation settings (the perception node's parameters of the same names)."""

    max_points: int = 100_000
    sample_points: int = 2048
    object_points: int = 512
    crop: bool = False
    crop_min: tuple[float, float, float] = (-1.0, -1.0, -0.05)
    crop_max: tuple[float, float, float] = (1.0, 1.0, 1.0)
    remove_plane: bool = True
    plane_distance: float = 0.005
    plane_max_tilt: float = 10.0  # degrees
    plane_max_offset: float = 0.02  # m
    voxel_size: float = 0.0
    cluster_tolerance: float = 0.01
    cluster_max_size: float = 1.0
    max_objects: int = 16
    outlier_neighbors: int = 10
    outlier_std_ratio: float = 2.0
    min_points: int = 32


#: The name used before the segmentation existed (bench/bench_nodes.py and older callers import it).
Preprocess = SceneConfig


@dataclass
class TablePlane:
    """normal . p + offset = 0 in the table frame; normal is a unit vector with z > 0."""

    normal: np.ndarray
    offset: float

    @property
    def height(self) -> float:
        """z of the plane at the table frame's origin, m."""
        return self.height_at(0.0, 0.0)

    def height_at(self, x: float, y: float) -> float:
        """z of the plane at (x, y) of the table frame, m."""
        return -(self.offset + float(self.normal[0]) * x + float(self.normal[1]) * y) / float(self.normal[2])

    @property
    def tilt(self) -> float:
        """Angle between the plane's normal and z, degrees."""
        return math.degrees(math.acos(min(1.0, abs(float(self.normal[2])))))

    def in_frame(self, to_table: RigidTransform) -> tuple[np.ndarray, float]:
        """The same plane in the frame whose points `to_table` maps into the table frame."""
        n = to_table.rotation.T @ self.normal
        return n, float(self.offset + self.normal @ to_table.translation)


@dataclass
class SceneObject:
    """One object: a sample of at most `object_points` of its points (table frame, float64) after outlier
    removal, and all its clustered points before both (`cluster`; None where the object was made without one).
    The filter trims the far edge of a top face, which the camera samples sparsest, and a centre of mass taken
    from the view's outline needs it; pose tracking registers to a model of the whole cluster, since a random
    sample of each cloud lies up to a few millimetres off the previous cloud's sample."""

    points: np.ndarray
    cluster: np.ndarray | None = None

    @property
    def centroid(self) -> np.ndarray:
        return self.points.mean(axis=0)

    @property
    def whole(self) -> np.ndarray:
        """All its clustered points (its sample where it was made without them)."""
        return self.cluster if self.cluster is not None else self.points


@dataclass
class Scene:
    """What `segment` found. `reason` says why there is no object when `objects` is empty."""

    objects: list[SceneObject]
    finite_points: int
    plane: TablePlane | None = None
    plane_note: str = ""  # why no plane was removed, when remove_plane is on and none was
    above_points: int = 0  # points left after crop and plane removal (before subsampling)
    clustered_points: int = 0  # points of the sample that were clustered
    cell: float = 0.0  # m, the cell side the clustering used
    dropped: list[str] = field(default_factory=list)  # clusters that are not objects, and why
    reason: str = ""
    above: np.ndarray | None = None  # the points after subsampling, crop, plane and grid (steps 1-4), frame of to_table
    to_table: RigidTransform = field(default_factory=RigidTransform.identity)

    def surface(self, obj: SceneObject) -> np.ndarray:
        """All the points of `above` within the clustering's cell side of the object's clustered points, table
        frame: the object as densely as the cloud has it, where the clustering saw only a sample of
        `sample_points` (the pose tracker's reference model: each cloud's sample lies millimetres off the last
        one's, and a top face seen at a grazing angle is sampled centimetres apart). Points that close to the
        cluster would have joined it. Its cluster (or points) when the scene keeps no points."""
        from scipy.spatial import cKDTree

        pts = obj.whole
        reach = self.cell
        if self.above is None or not len(self.above) or reach <= 0:
            return pts
        lo, hi = pts.min(axis=0) - reach, pts.max(axis=0) + reach
        near = self.to_table.apply(self.above).astype(np.float64)
        box = np.all((near >= lo) & (near <= hi), axis=1)
        near = near[box]
        if not len(near):
            return pts
        d, _ = cKDTree(pts).query(near, distance_upper_bound=reach)
        return near[np.isfinite(d)]


# ------------------------------------------------------------------------------------------------- basics
def finite_rows(points: np.ndarray) -> np.ndarray:
    """The rows of an (N, 3) array whose three coordinates are finite."""
    ok = np.isfinite(points[:, 0]) & np.isfinite(points[:, 1]) & np.isfinite(points[:, 2])
    return points if ok.all() else np.compress(ok, points, axis=0)


def random_rows(points: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """At most k rows drawn uniformly without replacement (in their original order)."""
    n = len(points)
    if n <= k:
        return points
    return np.take(points, np.sort(rng.choice(n, size=int(k), replace=False)), axis=0)


def crop_rows(points: np.ndarray, lo, hi) -> np.ndarray:
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    ok = np.ones(len(points), dtype=bool)
    for i in range(3):
        ok &= (points[:, i] >= lo[i]) & (points[:, i] <= hi[i])
    return np.compress(ok, points, axis=0)


def voxel_downsample(points: np.ndarray, size: float) -> np.ndarray:
    """One point per occupied cube of side `size` (m): the mean of the points in it (like open3d's)."""
    if size <= 0 or len(points) == 0:
        return points
    cells = np.floor(points / size).astype(np.int64)
    cells -= cells.min(axis=0)
    dims = cells.max(axis=0) + 1
    keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    out = np.empty((len(counts), 3), dtype=np.float64)
    for i in range(3):
        out[:, i] = np.bincount(inverse, weights=points[:, i], minlength=len(counts)) / counts
    return out.astype(points.dtype)


# --------------------------------------------------------------------------------------------- table plane
def _plane_distances(points: np.ndarray, normals: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(M, H) signed distances of M points to H planes, without a BLAS call (see RigidTransform.apply)."""
    x, y, z = points[:, 0:1], points[:, 1:2], points[:, 2:3]
    return x * normals[None, :, 0] + y * normals[None, :, 1] + z * normals[None, :, 2] + offsets[None, :]


def _acceptable(normals: np.ndarray, offsets: np.ndarray, cfg: SceneConfig) -> np.ndarray:
    cos_tilt = math.cos(math.radians(cfg.plane_max_tilt))
    with np.errstate(divide="ignore", invalid="ignore"):
        height = -offsets / normals[:, 2]
    return (normals[:, 2] >= cos_tilt - 1e-12) & (np.abs(height) <= cfg.plane_max_offset)


def fit_table_plane(sample: np.ndarray, cfg: SceneConfig, rng: np.random.Generator) -> TablePlane | None:
    """The horizontal-enough plane near z = 0 with the most inliers in `sample` (table frame), refined by least
    squares on its inliers; None if no hypothesis qualifies."""
    if len(sample) < 3:
        return None
    # Draw the three points of each hypothesis near z = 0, where the table must be (a tilted table still crosses
    # this band near the origin), so that objects standing on it rarely provide hypotheses.
    reach = cfg.plane_max_offset + cfg.plane_distance + BAND_MARGIN
    band = np.flatnonzero(np.abs(sample[:, 2]) <= reach)
    if len(band) < 3:
        return None
    tri = sample[band[rng.integers(0, len(band), (PLANE_ITERATIONS, 3))]]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    good = norm > 1e-12
    normals = normals[good] / norm[good, None]
    normals *= np.where(normals[:, 2:3] < 0, -1.0, 1.0)
    offsets = -np.einsum("ij,ij->i", normals, tri[good, 0])
    keep = _acceptable(normals, offsets, cfg)
    if not keep.any():
        return None
    normals, offsets = normals[keep], offsets[keep]
    counts = (np.abs(_plane_distances(sample, normals, offsets)) <= cfg.plane_distance).sum(axis=0)
    best = int(np.argmax(counts))
    inliers = sample[np.abs(_plane_distances(sample, normals[best:best + 1], offsets[best:best + 1])[:, 0])
                     <= cfg.plane_distance]
    plane = TablePlane(normals[best], float(offsets[best]))
    if len(inliers) >= 3:  # least-squares refinement: the normal is the smallest principal axis
        centre = inliers.mean(axis=0)
        _, _, vt = np.linalg.svd(inliers - centre, full_matrices=False)
        n = vt[2] if vt[2][2] >= 0 else -vt[2]
        refined = TablePlane(n, float(-n @ centre))
        if _acceptable(refined.normal[None], np.array([refined.offset]), cfg)[0]:
            plane = refined
    return plane


def _cell_keys(cells: np.ndarray, dims: np.ndarray) -> np.ndarray:
    key = cells[:, 0].copy()
    for i in range(1, cells.shape[1]):
        key = key * dims[i] + cells[:, i]
    return key


def _contains(sorted_keys: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mask of `keys` present in `sorted_keys`, their positions there)."""
    pos = np.minimum(np.searchsorted(sorted_keys, keys), len(sorted_keys) - 1)
    return sorted_keys[pos] == keys, pos


def _near_cells(sorted_keys: np.ndarray, keys: np.ndarray, dims: np.ndarray) -> np.ndarray:
    """For each x-y cell key of `keys`: whether it or one of the 8 cells around it is in `sorted_keys`."""
    near = np.zeros(len(keys), dtype=bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            near |= _contains(sorted_keys, keys + dx * dims[1] + dy)[0]
    return near


def plane_is_table(sample: np.ndarray, plane: TablePlane, cfg: SceneConfig) -> bool:
    """True if part of the plane lies away from the objects on it: at least TABLE_FREE_SHARE of the sample's
    inliers have no point above the plane in their x-y cell or the 8 around it (cells of side
    max(cluster_tolerance, 1 cm)); if it cuts through no object: at most TABLE_CUT_SHARE of its inliers' cells
    also hold points above and just below it (a plane through the lower faces of objects in a cloud without the
    table; a table's area is free of both, a wall behind it crosses only its edge), also point by point where
    more than TABLE_BELOW_SHARE of the sample lies just below it: at most TABLE_THROUGH_SHARE lies below points
    above it (more: the flat top of a ring or a tray in a cloud without the table, with the other objects' lower
    parts below it)."""
    dist = _plane_distances(sample, plane.normal[None], np.array([plane.offset]))[:, 0]
    inliers = sample[np.abs(dist) <= cfg.plane_distance, :2]
    above = sample[dist > cfg.plane_distance, :2]
    if len(inliers) < 3:
        return False
    if len(above) == 0:
        return True  # only a plane: an empty table
    size = max(cfg.cluster_tolerance, 0.01)
    below = sample[(dist < -cfg.plane_distance) & (dist > -(cfg.plane_max_offset + BAND_MARGIN)), :2]
    cells_in, cells_up, cells_down = (np.floor(p / size).astype(np.int64) for p in (inliers, above, below))
    occupied = [c for c in (cells_in, cells_up, cells_down) if len(c)]
    lo = np.min([c.min(axis=0) for c in occupied], axis=0) - 1  # a border: the neighbours' keys stay distinct
    dims = np.max([c.max(axis=0) for c in occupied], axis=0) - lo + 2
    up = np.unique(_cell_keys(cells_up - lo, dims))
    key_in = _cell_keys(cells_in - lo, dims)
    if len(below) > TABLE_BELOW_SHARE * len(sample):
        # many points below: the table's depth noise, a lower surface beside it, or objects that stand through it
        # (points clearly above the noise above them, in the same x-y cell or the 8 around it)
        high = np.floor(sample[dist > 2.0 * cfg.plane_distance, :2] / size).astype(np.int64)
        high_keys = np.unique(_cell_keys(high - lo, dims))
        through = _near_cells(high_keys, _cell_keys(cells_down - lo, dims), dims)
        if int(through.sum()) > max(3, TABLE_THROUGH_SHARE * len(sample)):
            return False
    if len(below):
        # the share of the plane's cells with points above and just below: the object's faces through which a
        # plane of a table-less cloud runs, not a table's area (a wall behind it or mixed pixels: its edges)
        plane_cells = np.unique(key_in)
        down = np.unique(_cell_keys(cells_down - lo, dims))
        if (_contains(up, plane_cells)[0] & _contains(down, plane_cells)[0]).mean() > TABLE_CUT_SHARE:
            return False
    free = int((~_near_cells(up, key_in, dims)).sum())
    return free >= max(3, TABLE_FREE_SHARE * len(inliers))


# --------------------------------------------------------------------------------------- clusters, outliers
def cell_clusters(points: np.ndarray, size: float) -> tuple[np.ndarray, int]:
    """Labels of the points (0..K-1) when occupied cubic cells of side `size` that touch are joined, and the
    number of occupied cells."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    cells = np.floor(points / size).astype(np.int64)
    cells -= cells.min(axis=0) - 1  # a free border: neighbour keys never wrap around
    dims = cells.max(axis=0) + 2
    keys, inverse = np.unique(_cell_keys(cells, dims), return_inverse=True)
    m = len(keys)
    rows, cols = [], []
    for dx, dy, dz in _HALF_OFFSETS:
        hit, pos = _contains(keys, keys + (dx * dims[1] + dy) * dims[2] + dz)
        rows.append(np.flatnonzero(hit))
        cols.append(pos[hit])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), dtype=np.int8), (r, c)), shape=(m, m))
    _, labels = connected_components(graph, directed=False)
    return labels[inverse.reshape(-1)], m


def outlier_mask(points: np.ndarray, k: int, std_ratio: float) -> np.ndarray:
    """Statistical outlier removal: keep points whose mean distance to their k nearest neighbours is at most the
    mean of those means plus std_ratio standard deviations (open3d's remove_statistical_outlier)."""
    from scipy.spatial import cKDTree

    if k <= 0 or len(points) <= k:
        return np.ones(len(points), dtype=bool)
    d, _ = cKDTree(points).query(points, k=k + 1)
    mean = d[:, 1:].mean(axis=1)
    return mean <= mean.mean() + std_ratio * mean.std()


def in_range(points: np.ndarray) -> np.ndarray:
    """The rows within MAX_COORD of the origin along every axis."""
    ok = np.ones(len(points), dtype=bool)
    for i in range(3):
        ok &= np.abs(points[:, i]) <= MAX_COORD
    return points if ok.all() else np.compress(ok, points, axis=0)


# ------------------------------------------------------------------------------------------------ pipeline
def _clean(points: np.ndarray, cfg: SceneConfig, to_table: RigidTransform | None, rng: np.random.Generator,
           scene: Scene) -> np.ndarray:
    """Steps 1-5 of the module docstring: the subsample (table frame, float64) above the table."""
    pts = np.asarray(points)
    if pts.dtype not in (np.float32, np.float64):
        pts = pts.astype(np.float64)
    pts = finite_rows(pts.reshape(-1, 3))
    scene.finite_points = len(pts)
    pts = random_rows(pts, cfg.max_points, rng)
    to_table = to_table if to_table is not None else RigidTransform.identity()
    if cfg.crop and len(pts):
        pts, to_table = crop_rows(to_table.apply(pts), cfg.crop_min, cfg.crop_max), RigidTransform.identity()
    if cfg.remove_plane and len(pts) >= max(3, cfg.min_points):  # fewer cannot hold an object anyway
        sample = in_range(to_table.apply(random_rows(pts, PLANE_SAMPLE, rng)).astype(np.float64))
        plane = fit_table_plane(sample, cfg, rng)
        if plane is None:
            scene.plane_note = (f"no plane within {cfg.plane_max_tilt:g} deg of horizontal and "
                                f"{cfg.plane_max_offset:g} m of z = 0 (is the table the plane z = 0 of the table "
                                "frame?)")
        elif not plane_is_table(sample, plane, cfg):
            scene.plane_note = (f"the plane at z = {plane.height:.3f} m lies only under the objects or cuts "
                                "through them (no table in view): kept")
        else:
            scene.plane = plane
            n, d = plane.in_frame(to_table)
            n = n.astype(pts.dtype)
            dist = pts[:, 0] * n[0] + pts[:, 1] * n[1] + pts[:, 2] * n[2] + pts.dtype.type(d)
            pts = np.compress(dist > cfg.plane_distance, pts, axis=0)  # the table and anything below it
    if cfg.voxel_size > 0 and len(pts):
        pts = voxel_downsample(pts, cfg.voxel_size)
    scene.above_points = len(pts)
    scene.above, scene.to_table = pts, to_table
    return in_range(to_table.apply(random_rows(pts, cfg.sample_points, rng)).astype(np.float64))


def _too_few(n: int, cfg: SceneConfig, scene: Scene) -> str:
    if scene.plane is not None:
        return f"only {n} points left above the table plane (min_points {cfg.min_points}): no object on the table"
    return f"only {n} points left after preprocessing (min_points {cfg.min_points})"


def segment(points: np.ndarray, cfg: SceneConfig, to_table: RigidTransform | None = None,
            rng: np.random.Generator | None = None) -> Scene:
    """(N, 3) points in a sensor frame (`to_table` maps them into the table frame; None = already there) -> the
    objects on the table, largest first. Never raises for bad data: `Scene.reason` says why nothing was found."""
    rng = rng if rng is not None else np.random.default_rng(0)
    scene = Scene(objects=[], finite_points=0)
    pts = _clean(points, cfg, to_table, rng, scene)
    if scene.finite_points == 0:
        scene.reason = "the cloud has no finite points"
        return scene
    scene.clustered_points = len(pts)
    if len(pts) < cfg.min_points:
        scene.reason = _too_few(len(pts), cfg, scene)
        return scene
    size = cfg.cluster_tolerance
    labels, cells = cell_clusters(pts, size)
    while len(pts) < 1.5 * cells and size < 4 * cfg.cluster_tolerance:
        size *= 1.5
        labels, cells = cell_clusters(pts, size)
    scene.cell = size
    order = np.argsort(labels, kind="stable")
    sizes = np.bincount(labels)
    starts = np.concatenate([[0], np.cumsum(sizes)])
    small = wide = few = 0
    for label in np.argsort(-sizes, kind="stable"):
        if sizes[label] < cfg.min_points:
            small += 1
            continue
        obj = pts[order[starts[label]:starts[label + 1]]]
        extent = float(max(obj[:, i].max() - obj[:, i].min() for i in range(3)))
        if extent > cfg.cluster_max_size:
            wide += 1
            scene.dropped.append(f"a cluster of {len(obj)} points {extent:.2f} m across (cluster_max_size "
                                 f"{cfg.cluster_max_size:g} m)")
            continue
        if len(scene.objects) >= cfg.max_objects:
            scene.dropped.append(f"a cluster of {len(obj)} points beyond max_objects {cfg.max_objects}")
            continue
        sample = random_rows(obj, cfg.object_points, rng)
        kept = sample[outlier_mask(sample, cfg.outlier_neighbors, cfg.outlier_std_ratio)]
        if len(kept) < cfg.min_points:
            few += 1
            continue
        scene.objects.append(SceneObject(kept, obj))
    if len(scene.objects) > 1:  # the table: its plane, else z = 0 of the table frame (as the tracker takes it)
        table = scene.plane if scene.plane is not None else TablePlane(np.array([0.0, 0.0, 1.0]), 0.0)
        scene.objects = _join_floating(scene.objects, table, cfg.object_points, rng)
    if small:
        scene.dropped.append(f"{small} cluster(s) of fewer than min_points {cfg.min_points} points")
    if few:
        scene.dropped.append(f"{few} cluster(s) with fewer than min_points {cfg.min_points} points after outlier "
                             "removal")
    if not scene.objects:
        parts = [f"no object found in {scene.clustered_points} points"
                 + (" above the table plane" if scene.plane is not None else "")]
        if wide:
            parts.append(f"{wide} cluster(s) wider than cluster_max_size {cfg.cluster_max_size:g} m"
                         + (f" ({scene.plane_note})" if scene.plane_note else ""))
        if small or few:
            parts.append(f"{small + few} cluster(s) of fewer than min_points {cfg.min_points} points")
        scene.reason = "; ".join(parts)
    return scene


def _covered(outline: np.ndarray, points: np.ndarray) -> float:
    """Share of the x-y `points` inside the convex hull of the x-y `outline` (0 for a degenerate outline)."""
    from scipy.spatial import Delaunay, QhullError

    lo, hi = outline[:, :2].min(axis=0), outline[:, :2].max(axis=0)
    near = np.all((points[:, :2] >= lo) & (points[:, :2] <= hi), axis=1)
    if not near.any():  # no point within the outline's box: skip the hull
        return 0.0
    try:
        return float(np.count_nonzero(Delaunay(outline[:, :2]).find_simplex(points[near, :2]) >= 0)) / len(points)
    except (QhullError, ValueError):
        return 0.0


def _join_floating(objects: list[SceneObject], plane: TablePlane, object_points: int,
                   rng: np.random.Generator) -> list[SceneObject]:
    """Step 8 of the module docstring: an object that floats joins the nearest object below it that holds it up,
    until none does; largest first. Outlines are those of the objects' samples (`points`, at most object_points)."""
    def heights(obj: SceneObject) -> tuple[float, float]:
        z = obj.whole @ plane.normal + plane.offset
        return float(z.min()), float(z.max())

    objects = list(objects)
    joined = True
    while joined:  # a stack joins from the top down, one pair at a time
        joined = False
        span = [heights(o) for o in objects]
        for t in sorted(range(len(objects)), key=lambda k: -span[k][0]):
            low = span[t][0]
            if low <= FLOAT_HEIGHT:
                break
            # a support stands up from the table (not the table's remnant) and reaches up to within FLOAT_GAP of
            # the top: a hand above an object is no part of it
            below = [i for i, (lo, hi) in enumerate(span) if i != t and lo < low and hi - lo > FLOAT_HEIGHT
                     and low - hi <= FLOAT_GAP
                     and max(_covered(objects[t].points, objects[i].points),
                             _covered(objects[i].points, objects[t].points)) >= FLOAT_OVERLAP]
            if not below:
                continue
            i = max(below, key=lambda k: span[k][1])  # the nearest below
            top, base = objects[t], objects[i]
            objects[i] = SceneObject(random_rows(np.concatenate([base.points, top.points]), object_points, rng),
                                     np.concatenate([base.whole, top.whole]))
            del objects[t]
            joined = True
            break
    return sorted(objects, key=lambda o: -len(o.whole))


def preprocess(points: np.ndarray, cfg: SceneConfig, rng: np.random.Generator | None = None) -> np.ndarray:
    """The whole cloud (table frame) cleaned as one object, without splitting it: finite points, crop, table
    plane, voxel grid, subsample to sample_points, outlier removal. ValueError if fewer than min_points remain.
    Kept for callers that encode a cloud of one object (bench/bench_nodes.py)."""
    rng = rng if rng is not None else np.random.default_rng(0)
    scene = Scene(objects=[], finite_points=0)
    pts = _clean(points, cfg, None, rng, scene)
    pts = pts[outlier_mask(pts, cfg.outlier_neighbors, cfg.outlier_std_ratio)]
    if len(pts) < cfg.min_points:
        raise ValueError(f"only {len(pts)} points left after preprocessing (min_points {cfg.min_points})")
    return pts.astype(np.float32)


def outline_xy(points: np.ndarray) -> np.ndarray:
    """The convex hull of the points' x-y projection, counter-clockwise and closed (first vertex repeated),
    (K+1, 2); the bounding rectangle when the hull is degenerate (collinear or fewer than 3 points)."""
    from scipy.spatial import ConvexHull
    from scipy.spatial import QhullError

    xy = np.asarray(points, dtype=np.float64)[:, :2]
    if len(xy) == 0:
        return np.zeros((0, 2))
    try:
        ring = xy[ConvexHull(xy).vertices]  # counter-clockwise for 2-D input
    except (QhullError, ValueError):
        (x0, y0), (x1, y1) = xy.min(axis=0), xy.max(axis=0)
        ring = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    return np.vstack([ring, ring[:1]])


def hull_centroid(xy: np.ndarray, min_area: float = 1e-9) -> tuple[np.ndarray, float] | None:
    """Area centroid (2,) and area (m^2) of the convex hull of 2-D points; None when the hull spans less than
    min_area (collinear or fewer than 3 points)."""
    from scipy.spatial import ConvexHull
    from scipy.spatial import QhullError

    pts = np.asarray(xy, dtype=np.float64)
    try:
        ring = pts[ConvexHull(pts).vertices]
    except (QhullError, ValueError):
        return None
    x, y = ring[:, 0], ring[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum()
    if abs(area) < min_area:
        return None
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6.0 * area), float(abs(area))
