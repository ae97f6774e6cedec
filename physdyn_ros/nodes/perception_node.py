"""Perception: an object's point cloud -> its learned shape feature (ShapeFeature), once per cloud.

The cloud must already be in the table frame (this node does not use tf): clouds in any other frame are dropped
with a warning. Preprocessing: keep finite points, random subsample to max_points (bounds time and memory for
huge clouds), optional crop box, optional removal of the table plane (RANSAC, only a near-horizontal plane near
z = 0), optional voxel grid, statistical outlier removal. Then Predictor.encode.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass

import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from ..conventions import TABLE_FRAME
from ..ros.throttle import ReasonThrottle
from ..msg import ShapeFeature
from ..ros.cloud import cloud_size, cloud_to_xyz
from ..ros.convert import point, vector3
from ..ros.model import load_predictor
from ..ros.params import declare
from ..ros.run import run_node

#: SensorDataQoS (best effort, volatile) but depth 1: only the newest cloud matters, and a queue of huge clouds
#: would hold hundreds of MB.
CLOUD_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)
#: Latched: a node that starts later still receives the last feature.
FEATURE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)


@dataclass
class Preprocess:
    """Cloud cleaning settings (the node's parameters of the same names)."""

    max_points: int = 100_000
    crop: bool = False
    crop_min: tuple[float, float, float] = (-1.0, -1.0, -0.05)
    crop_max: tuple[float, float, float] = (1.0, 1.0, 1.0)
    remove_plane: bool = False
    plane_distance: float = 0.005
    plane_max_tilt: float = 10.0  # degrees
    plane_max_offset: float = 0.02  # m
    voxel_size: float = 0.0
    outlier_neighbors: int = 20
    outlier_std_ratio: float = 2.0
    min_points: int = 32


def _o3d(points: np.ndarray):
    import open3d as o3d

    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))


def remove_table_plane(points: np.ndarray, cfg: Preprocess, seed: int = 0) -> np.ndarray:
    """Drop the inliers of the dominant plane if it is the table: normal within plane_max_tilt of z and height
    within plane_max_offset of z = 0. Any other plane (an object's face) is left alone."""
    if len(points) < 3:
        return points
    import open3d as o3d

    o3d.utility.random.seed(seed)  # RANSAC draws from open3d's global generator: reproducible results
    (a, b, c, d), inliers = _o3d(points).segment_plane(cfg.plane_distance, 3, 200)
    norm = math.sqrt(a * a + b * b + c * c)
    tilt = math.degrees(math.acos(min(1.0, abs(c) / norm)))
    height = -d / c if abs(c) > 1e-9 else math.inf
    if tilt > cfg.plane_max_tilt or abs(height) > cfg.plane_max_offset:
        return points
    keep = np.ones(len(points), dtype=bool)
    keep[np.asarray(inliers, dtype=np.int64)] = False
    return points[keep & (points[:, 2] > height)]  # and anything below the table


def preprocess(points: np.ndarray, cfg: Preprocess) -> np.ndarray:
    """Finite (N, 3) points of one object (table frame) -> the cleaned cloud. ValueError if too few remain."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) > cfg.max_points:  # callers normally subsample while reading (cloud_to_xyz)
        pts = pts[np.random.default_rng(0).choice(len(pts), cfg.max_points, replace=False)]
    if cfg.crop:
        lo, hi = np.asarray(cfg.crop_min), np.asarray(cfg.crop_max)
        pts = pts[np.all((pts >= lo) & (pts <= hi), axis=1)]
    if cfg.remove_plane:
        pts = remove_table_plane(pts, cfg)
    if cfg.voxel_size > 0 and len(pts):
        pts = np.asarray(_o3d(pts).voxel_down_sample(cfg.voxel_size).points)
    if cfg.outlier_neighbors > 0 and len(pts) > cfg.outlier_neighbors:
        _, idx = _o3d(pts).remove_statistical_outlier(cfg.outlier_neighbors, cfg.outlier_std_ratio)
        pts = pts[np.asarray(idx, dtype=np.int64)]
    if len(pts) < cfg.min_points:
        raise ValueError(f"only {len(pts)} points left after preprocessing (min_points {cfg.min_points})")
    return pts.astype(np.float32)


class PerceptionNode(Node):
    """Subscribes `cloud`, publishes `shape_feature`."""

    def __init__(self, **kwargs) -> None:
        super().__init__("perception", **kwargs)
        model_path = declare(self, "model_path", "", "checkpoint to load; empty = the shipped default model",
                             read_only=True)
        device = declare(self, "device", "cpu", "torch device for the encoder", read_only=True)
        threads = declare(self, "num_threads", 1, "torch intra-op threads (set explicitly: no oversubscription)",
                          read_only=True, low=1, high=256)
        self.table_frame: str = declare(self, "table_frame", TABLE_FRAME, "clouds must be in this frame (no tf "
                                        "lookup); the feature is published in it", read_only=True)
        declare(self, "object_id", "object", "object_id written into each ShapeFeature")
        d = Preprocess()
        declare(self, "max_points", d.max_points, "clouds with more points are randomly subsampled to this many "
                "while being read (bounds time and memory)", low=16)
        declare(self, "crop", d.crop, "keep only points inside the box crop_min..crop_max (table frame)")
        declare(self, "crop_min", list(d.crop_min), "x, y, z lower corner of the crop box, m")
        declare(self, "crop_max", list(d.crop_max), "x, y, z upper corner of the crop box, m")
        declare(self, "remove_plane", d.remove_plane, "remove the table plane found by RANSAC (a plane within "
                "plane_max_tilt of horizontal and plane_max_offset of z = 0) and the points below it")
        declare(self, "plane_distance", d.plane_distance, "RANSAC inlier distance, m", low=1e-5, high=1.0)
        declare(self, "plane_max_tilt", d.plane_max_tilt, "largest tilt of the table plane, degrees", low=0.0,
                high=90.0)
        declare(self, "plane_max_offset", d.plane_max_offset, "largest |height| of the table plane, m", low=0.0)
        declare(self, "voxel_size", d.voxel_size, "voxel grid downsampling size, m; 0 = off", low=0.0, high=1.0)
        declare(self, "outlier_neighbors", d.outlier_neighbors, "statistical outlier removal: neighbours per "
                "point; 0 = off", low=0, high=1000)
        declare(self, "outlier_std_ratio", d.outlier_std_ratio, "statistical outlier removal: std-dev ratio",
                low=0.1, high=100.0)
        declare(self, "min_points", d.min_points, "fewer points after preprocessing: no feature (warning)",
                low=1)
        self.predictor = load_predictor(self, model_path, device, threads)
        self._rng = np.random.default_rng(0)
        self.processed = 0
        self.last_error = ""
        self._warn = ReasonThrottle(self.get_logger().warning, 2.0)
        self.pub = self.create_publisher(ShapeFeature, "shape_feature", FEATURE_QOS)
        self.create_subscription(PointCloud2, "cloud", self.on_cloud, CLOUD_QOS)
        self.get_logger().info(f"ready: encoding clouds in frame '{self.table_frame}' with model "
                               f"{self.predictor.model_id}")

    def config(self) -> Preprocess:
        """The preprocessing settings, read from the parameters now (they may change at run time)."""
        p = {name: self.get_parameter(name).value for name in Preprocess.__dataclass_fields__}
        p["crop_min"], p["crop_max"] = tuple(p["crop_min"]), tuple(p["crop_max"])
        return Preprocess(**p)

    def _reject(self, msg: PointCloud2, reason: str) -> None:
        self.last_error = reason
        self._warn(f"cloud ({cloud_size(msg)} points, frame '{msg.header.frame_id}') ignored: {reason}", reason)

    def encode_cloud(self, msg: PointCloud2) -> ShapeFeature:
        """Cloud message -> ShapeFeature; ValueError with the reason when the cloud cannot be used."""
        if msg.header.frame_id != self.table_frame:
            raise ValueError(f"frame_id '{msg.header.frame_id}' is not the table frame '{self.table_frame}' "
                             "(transform the cloud first; this node does not use tf)")
        cfg = self.config()
        pts = cloud_to_xyz(msg, skip_nans=True, max_points=cfg.max_points, rng=self._rng)
        if len(pts) == 0:
            raise ValueError("the cloud has no finite points" if cloud_size(msg) else "the cloud is empty")
        pts = preprocess(pts, cfg)
        code = self.predictor.encode(pts)
        return ShapeFeature(header=msg.header, object_id=self.get_parameter("object_id").value,
                            model_id=self.predictor.model_id,
                            feature=np.asarray(code.feature, dtype=np.float32).reshape(-1).tolist(),
                            heading=float(code.heading), centroid=point(code.centroid),
                            half_extents=vector3(code.half_extents), num_points=int(len(pts)))

    def on_cloud(self, msg: PointCloud2) -> None:
        t0 = time.monotonic()
        try:
            feature = self.encode_cloud(msg)
        except ValueError as exc:
            self._reject(msg, str(exc))
            return
        except Exception as exc:  # noqa: BLE001 - one bad cloud must not kill the node
            self._reject(msg, f"{type(exc).__name__}: {exc}")
            return
        self.pub.publish(feature)
        self.processed += 1
        self.get_logger().debug(f"feature from {cloud_size(msg)} points ({feature.num_points} kept) in "
                                f"{1e3 * (time.monotonic() - t0):.1f} ms")


def main(args: list[str] | None = None) -> int:
    return run_node(PerceptionNode, "perception", args)


if __name__ == "__main__":
    sys.exit(main())
