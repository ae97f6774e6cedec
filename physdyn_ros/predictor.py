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
"""Predictor: the learned dynamics model behind a small numpy API (torch inside; no rclpy, no pybullet).

    from physdyn_ros.predictor import Predictor
    pred = Predictor.load()                       # the shipped model (physdyn_ros/models/default.pt)
    code = pred.encode(cloud)                     # (N, 3) points in the table frame, once per object
    traj = pred.rollout(code, lin_vel, ang_vel, horizon=60)
    traj.positions[-1], traj.orientations[-1], traj.topple_probability
    many = pred.rollout_batch(code, lin_vels (B, 3), ang_vels (B, 3))    # e.g. candidate pushes of a planner

Frames: the cloud and all states are in the table frame (z up, REP 103); velocities in the world frame, as
pybullet reports them. Internally the roll-out runs in the canonical frame C of the cloud (heading, see
docs/architecture.md "Learning frame"), which makes predictions exactly equivariant to yaw and translation.
Orientations: unless `orientation` is given, the object's orientation at the start is taken as the identity,
i.e. returned orientations are the rotation relative to the pose in which the cloud was observed.

`physdyn predict --cloud file.npy|.ply|.xyz --lin-vel x y z --ang-vel x y z --horizon 60` prints the final pose.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence, Union

import numpy as np
from scipy.spatial.transform import Rotation

from .conventions import DT
from .learn.frames import c_to_world, canonicalize_cloud, compose_rotations, world_to_c
from .learn.rules import HEAD_TIMING_STEPS, consistent_topple, flat_unless_toppling, settle, topple_with_head
from .learn.support import DESCRIPTOR_POINTS, support_descriptors
from .geometry import yaw_of
from .spread import DEFAULT_LEVEL, SPEEDS, RestSpread, SpreadCalibration, perturbed_twists, sensitivity, spread_path

__all__ = ["ShapeCode", "Trajectory", "TrajectoryBatch", "Observed", "Predictor", "load_cloud"]

#: Fewest points the topple fusion simulates (fewer make no solid: the model's probability stands).
MIN_FUSION_POINTS = 16


@dataclass(frozen=True)
class ShapeCode:
    """What the model needs to know about an object, computed once per object by Predictor.encode."""

    feature: np.ndarray  # (F,) float32 shape feature
    heading: float  # rad, yaw of frame C in the table frame
    # (3,) m, table frame: the default roll-out start, the estimated centre of mass for models with a
    # centre-of-mass head (model.com_head: a partial view's centroid lies cm off it), else the cloud's centroid
    centroid: np.ndarray
    half_extents: np.ndarray  # (3,) m, half sizes of the cloud's bounding box in frame C
    num_points: int  # points in the encoded cloud
    model_id: str = ""  # the model that made it (features of different models are not interchangeable)
    # (N, 3) m, the encoded cloud in the table frame (None for a code rebuilt from a shape feature message): the
    # topple fusion's physics simulates it (Predictor.topple_fusion)
    points: Optional[np.ndarray] = None


@dataclass(frozen=True)
class Trajectory:
    """A predicted trajectory: H+1 states, frame 0 = the given start state, DT apart."""

    dt: float
    positions: np.ndarray  # (H+1, 3) m, centre of mass, table frame
    orientations: np.ndarray  # (H+1, 4) x, y, z, w
    lin_vels: np.ndarray  # (H+1, 3) m/s, world frame
    ang_vels: np.ndarray  # (H+1, 3) rad/s, world frame
    topple_prob: np.ndarray  # (H+1,) probability that the object has toppled by each frame (frame 0: 0)
    # how far the shape and push lie from the training data (learn/topple.py): > 1 beyond 99.5 % of the training
    # inputs, a prediction to treat with caution; NaN for models without a topple head
    novelty: float = float("nan")
    spread: Optional[RestSpread] = None  # how far the true rest pose may lie (rollout(spread=True))

    @property
    def horizon(self) -> int:
        return len(self.positions) - 1

    @property
    def topple_probability(self) -> float:
        """Probability that the object topples at some point of the roll-out (max over frames)."""
        return float(self.topple_prob.max())

    @property
    def times(self) -> np.ndarray:
        return np.arange(len(self.positions)) * self.dt


@dataclass(frozen=True)
class TrajectoryBatch:
    """B trajectories, arrays with a leading batch dimension; `batch[i]` is a Trajectory."""

    dt: float
    positions: np.ndarray  # (B, H+1, 3)
    orientations: np.ndarray  # (B, H+1, 4)
    lin_vels: np.ndarray  # (B, H+1, 3)
    ang_vels: np.ndarray  # (B, H+1, 3)
    topple_prob: np.ndarray  # (B, H+1)
    novelty: Optional[np.ndarray] = None  # (B,) see Trajectory.novelty; None for models without a topple head

    def __len__(self) -> int:
        return len(self.positions)

    def __getitem__(self, i: int) -> Trajectory:
        novelty = float("nan") if self.novelty is None else float(self.novelty[i])
        return Trajectory(self.dt, self.positions[i], self.orientations[i], self.lin_vels[i], self.ang_vels[i],
                          self.topple_prob[i], novelty)

    @property
    def topple_probability(self) -> np.ndarray:
        """(B,) max topple probability per trajectory."""
        return self.topple_prob.max(axis=1)


@dataclass(frozen=True)
class Observed:
    """K observed states following the start state (frames 1..K), fed to the model before it runs free
    ("steps in" = K + 1 in the paper's friction experiment: lets the model infer friction from motion)."""

    positions: np.ndarray  # (K, 3)
    orientations: np.ndarray  # (K, 4)
    lin_vels: np.ndarray  # (K, 3)
    ang_vels: np.ndarray  # (K, 3)


# ------------------------------------------------------------------------------------------------- input checks
def _vector(value: Any, size: int, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {size} numbers, got {value!r}") from None
    if arr.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf: {arr.tolist()}")
    return arr


def _vectors(value: Any, size: int, name: str, batch: Optional[int] = None) -> np.ndarray:
    """(size,) or (B, size) finite array -> (B or 1, size)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an array of {size}-vectors") from None
    if arr.ndim == 1:
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != size or arr.shape[0] == 0:
        raise ValueError(f"{name} must have shape ({size},) or (B, {size}), got {np.shape(value)}")
    if batch is not None and arr.shape[0] not in (1, batch):
        raise ValueError(f"{name} has {arr.shape[0]} rows, expected 1 or {batch}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


def _quaternions(value: Any, name: str, batch: Optional[int] = None) -> np.ndarray:
    q = _vectors(value, 4, name, batch)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    if np.any(norm < 1e-9):
        raise ValueError(f"{name} must be non-zero quaternions (x, y, z, w)")
    return q / norm


#: m, the sizes of object the models were trained on (the broad world: 1.5-45 cm per axis, config/generate_broad.yaml)
MIN_OBJECT_SIZE, MAX_OBJECT_SIZE = 0.01, 0.6


def check_cloud(cloud: Any) -> np.ndarray:
    """An (N, 3) finite, non-empty float64 array, or ValueError naming the problem."""
    try:
        arr = np.asarray(cloud, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("cloud must be an (N, 3) array of numbers") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"cloud must have shape (N, 3), got {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError("cloud is empty (0 points)")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"cloud contains NaN or inf ({int(np.sum(~np.isfinite(arr)))} values)")
    # The extents along the cloud's principal axes: a point, a line or a sheet of points is not a solid object,
    # and the models were trained on objects of MIN_OBJECT_SIZE-MAX_OBJECT_SIZE (generate: push.size_limits).
    centred = arr - arr.mean(axis=0)
    axes = np.linalg.svd(centred[:: max(1, len(arr) // 4096)], full_matrices=False)[2]
    proj = centred @ axes.T
    extent = proj.max(axis=0) - proj.min(axis=0)  # largest first
    if extent[0] > MAX_OBJECT_SIZE:
        raise ValueError(f"cloud spans {extent[0]:.2f} m, larger than any trained object ({MAX_OBJECT_SIZE:g} m): "
                         "is it one object, cropped from the table, in metres?")
    if extent[0] < MIN_OBJECT_SIZE or extent[1] < MIN_OBJECT_SIZE:
        raise ValueError(f"cloud is degenerate: it spans only {extent[0] * 100:.2f} x {extent[1] * 100:.2f} cm "
                         "across its "
                         f"two main directions (a point or a line of points; objects measure at least "
                         f"{MIN_OBJECT_SIZE * 100:g} cm)")
    return arr


# ---------------------------------------------------------------------------------------------------- predictor
class Predictor:
    """A loaded model ready to predict; create with Predictor.load(). Not thread-safe: one per thread."""

    def __init__(self, model: Any, checkpoint: Mapping[str, Any], device: str = "cpu", path: str = "",
                 precision: str = "auto") -> None:
        from .learn.precision import resolve_precision

        self._model = model
        self._device = device
        # the precision of batched roll-outs (rollout_batch of more than one): "auto" is bf16 where the CPU has
        # bf16 arithmetic and the batch is large enough for it to pay (kernels.AUTO_BF16_ROWS), fp32 elsewhere;
        # batch 1 (rollout) always runs the float32 numpy kernel
        resolve_precision(precision, str(device))  # ValueError for an unknown one, or bf16 off the CPU
        self.precision: str = precision
        self.path = path
        self.model_id: str = str(checkpoint["model_id"])
        dataset = checkpoint.get("dataset") or {}
        manifest = dataset.get("manifest") or {}
        self.dt: float = float(manifest.get("dt", DT))
        self.num_points: int = int(model.cfg.num_points)
        # the shape feature: the dynamics network's (model.feature_dim numbers), then, for models with a
        # whole-push topple head, the cloud's support descriptors (learn/topple.py) that head needs
        self._topple = getattr(model, "topple", None)
        self._dynamics_dim = int(model.feature_dim)
        self.feature_dim: int = self._dynamics_dim + (self._topple.desc_dim if self._topple is not None else 0)
        self.max_horizon: int = int(model.cfg.max_horizon)
        # a fixed subsample per cloud size: predictions depend only on the cloud, never on call order
        self._subsets: dict[tuple[int, int], np.ndarray] = {}
        # whole-push topple probabilities of `rollout` fused with physics on the whole cloud's solid (None: the
        # model's own); see load(topple_fusion=...) and physdyn_ros.topple_fusion
        self.topple_fusion: Optional[Any] = None
        # turns a push's sensitivity into calibrated radii (rollout(spread=True)); None, with the reason in
        # spread_problem, for a checkpoint without a calibration of its own beside it
        self.spread_calibration: Optional[SpreadCalibration] = None
        self.spread_problem = "no spread calibration"

    def batch_precision(self, rows: int) -> str:
        """"fp32" or "bf16": the precision of a roll-out of `rows` trajectories (1: always the float32 kernel)."""
        from .learn.precision import resolve_precision

        if rows <= 1 or getattr(self._model.cfg, "cell", "lstm") != "lstm":
            return "fp32"
        return resolve_precision(self.precision, str(self._device), rows)

    @property
    def estimates_com(self) -> bool:
        """True if ShapeCode.centroid is the model's centre-of-mass estimate (a centre-of-mass head), False if
        it is the centroid of the points."""
        return self._model.com is not None

    @classmethod
    def load(cls, path: Union[str, os.PathLike, None] = None, device: str = "cpu",
             threads: Optional[int] = None, precision: str = "auto", topple_fusion: bool = False,
             friction: float = 0.5) -> "Predictor":
        """Load a checkpoint (None: the shipped default model) and warm it up.

        FileNotFoundError if the file does not exist; learn.checkpoint.CheckpointError (a RuntimeError) if it
        is corrupt, not a physdyn checkpoint, or incompatible with this code. `threads` sets torch's CPU
        threads (process-wide); for batch-1 latency 1 thread is fastest. `precision` of batched roll-outs:
        "auto" (bf16 matrix products where the CPU reports avx512_bf16 or amx_bf16 and no ONEDNN_MAX_CPU_ISA
        cap below bf16 is set, else fp32), "fp32" or
        "bf16" (forced; correct on any CPU, slower than fp32 without bf16 arithmetic); ValueError otherwise.
        "auto" keeps batches under kernels.AUTO_BF16_ROWS in fp32 (bf16 is no faster there). The model card
        states bf16's accuracy cost; batch_precision(rows) says which a batch runs in. Batch 1 runs the C kernel
        where it is built (learn/native.py; PHYSDYN_BATCH1_KERNEL=numpy forces the numpy kernel).

        `topple_fusion`: `rollout` of a cloud (or of a code encoded from one) fuses the model's whole-push topple
        probability with pybullet on the solid the cloud encloses, the push at `friction`, 20 % less and more
        friction, 10 % slower and faster (physdyn_ros.topple_fusion, weights stored beside the checkpoint:
        FileNotFoundError without them). Only for whole clouds (every side of the object sampled, at least
        MIN_FUSION_POINTS points, not flat: others keep the model's probability); the solid and five short
        simulations add about 25-120 ms to each call. Batched roll-outs stay the model's.
        """
        import torch

        from .learn.checkpoint import load_model
        from .resources import DEFAULT_MODEL

        if path is None:
            path = DEFAULT_MODEL
            if not Path(path).is_file():
                raise FileNotFoundError(f"no shipped model at {path}; train one with 'physdyn train --config "
                                        "config/model_default.yaml ...' and pass its model_best.pt")
        from .learn.native import use_c
        from .learn.precision import resolve_precision

        resolve_precision(precision, device)  # refuse a wrong precision before loading anything
        use_c()  # and a wrong batch-1 kernel (PHYSDYN_BATCH1_KERNEL)
        if threads is not None:
            torch.set_num_threads(int(threads))
        model, ckpt = load_model(path, map_location=device)
        model.to(device).eval()
        pred = cls(model, ckpt, device, str(path), precision)
        if topple_fusion:
            from .topple_fusion import ToppleFusion

            if pred._topple is None:
                raise ValueError(f"{path} has no whole-push topple head to fuse with physics")
            pred.topple_fusion = ToppleFusion.for_checkpoint(path, pred.model_id, friction)
        pred._load_spread(spread_path(path))
        pred._warm_up()
        return pred

    def _load_spread(self, path: Path) -> None:
        try:
            cal = SpreadCalibration.load(path)
        except FileNotFoundError:
            self.spread_problem = f"no spread calibration at {path} (fit one: physdyn fit-spread)"
            return
        except ValueError as exc:
            self.spread_problem = str(exc)
            return
        if cal.model_id != self.model_id:
            self.spread_problem = f"{path} was fitted for model {cal.model_id}, not {self.model_id}"
            return
        if DEFAULT_LEVEL not in cal.levels:
            self.spread_problem = f"{path} has no level {DEFAULT_LEVEL} (levels {list(cal.levels)})"
            return
        self.spread_calibration = cal

    def _warm_up(self) -> None:
        """Run the compiled roll-out a few times: TorchScript optimises a function on its first calls (the model
        alone: the topple fusion's physics has nothing to warm up)."""
        rng = np.random.default_rng(0)
        cloud = rng.uniform(-0.05, 0.05, size=(self.num_points, 3)) * (1.0, 0.6, 1.5)
        code = replace(self.encode(cloud), points=None)
        for _ in range(3):
            self.rollout(code, (0.5, 0.1, 0.0), (0.0, 0.0, 1.0), horizon=min(60, self.max_horizon))

    def close(self) -> None:
        """Release the topple fusion's pybullet client, if any (the model needs no closing)."""
        if self.topple_fusion is not None:
            self.topple_fusion.close()
            self.topple_fusion = None

    # ----------------------------------------------------------------------------------------------- encode
    def _subset(self, n: int, wanted: int = 0) -> np.ndarray:
        """The fixed subset of `wanted` (default num_points) of n points, as training's (windows.make_windows)."""
        wanted = wanted or self.num_points
        if (n, wanted) not in self._subsets:
            gen = np.random.default_rng(0)
            if n >= wanted:
                idx = np.sort(gen.permutation(n)[:wanted])
            else:  # repeat points: max pooling (and a hull, an extreme) is unchanged by duplicates
                idx = np.concatenate([np.arange(n), gen.integers(0, n, wanted - n)])
            self._subsets[(n, wanted)] = idx
        return self._subsets[(n, wanted)]

    def encode(self, cloud: Any, table_height: float = 0.0) -> ShapeCode:
        """Shape code of a cloud (N, 3) in the table frame (any N; resampled to num_points, centred).
        table_height: z of the table plane under the object (m; 0: the plane z = 0 of the table frame)."""
        return self.encode_many([cloud], [table_height])[0]

    def encode_many(self, clouds: Sequence[Any], table_heights: Optional[Sequence[float]] = None) -> list[ShapeCode]:
        """Shape codes of several clouds (each (N_i, 3), table frame) with one pass of the encoder: what a table
        with several objects costs (perception), about one encoder call instead of one per object. Each code
        equals encode(cloud) to float32 rounding. table_heights: z of the table plane under each object (m;
        default 0: the plane z = 0 of the table frame), which the topple head's support descriptors count from
        (the perception node passes the plane it fitted)."""
        import torch

        if not len(clouds):
            return []
        pts = [check_cloud(c) for c in clouds]
        heights = np.zeros(len(pts)) if table_heights is None else np.asarray(table_heights, dtype=np.float64)
        if heights.shape != (len(pts),) or not np.all(np.isfinite(heights)):
            raise ValueError(f"table_heights must be one finite height (m) per cloud ({len(pts)}), got "
                             f"{heights.tolist()}")
        canon = [canonicalize_cloud(p) for p in pts]
        local = [c.points for c in canon]
        sub = np.stack([loc[self._subset(len(p))] for loc, p in zip(local, pts)]).astype(np.float32)
        with torch.inference_mode():
            encoded = self._model.encode(torch.from_numpy(sub).to(self._device))
            features = encoded.float().cpu().numpy()
            offsets = self._model.com_estimate(encoded).double().cpu().numpy()
        if self._topple is not None:
            # the table under each object in its cloud's frame C, centred at its centroid
            table = heights - np.array([c.centroid[2] for c in canon])
            points = np.stack([loc[self._subset(len(p), DESCRIPTOR_POINTS)] for loc, p in zip(local, pts)]
                              ).astype(np.float32)  # as training's (float32 tensors)
            desc = support_descriptors(points, offsets, table)
            features = np.concatenate([features, desc.astype(np.float32)], axis=1)
        codes = []
        for c, loc, p, feature, offset in zip(canon, local, pts, features, offsets):
            codes.append(ShapeCode(feature=feature, heading=float(c.heading),
                                   centroid=c.centroid + c_to_world(offset, float(c.heading)),
                                   half_extents=0.5 * (loc.max(axis=0) - loc.min(axis=0)), num_points=int(len(p)),
                                   model_id=self.model_id, points=p.copy()))
        return codes

    def _check_code(self, code: ShapeCode) -> None:
        feature = np.asarray(code.feature)
        if feature.shape != (self.feature_dim,) or not np.all(np.isfinite(feature)):
            raise ValueError(f"shape feature must be {self.feature_dim} finite numbers, got shape {feature.shape}")
        if code.model_id and code.model_id != self.model_id:
            raise ValueError(f"shape code was encoded by model {code.model_id}, this predictor is {self.model_id}")
        if not math.isfinite(float(code.heading)):
            raise ValueError("shape code heading is not finite")

    def _code(self, shape: Any) -> ShapeCode:
        if isinstance(shape, ShapeCode):
            self._check_code(shape)
            return shape
        return self.encode(shape)

    def _check_horizon(self, horizon: Any) -> int:
        if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)):
            raise ValueError(f"horizon must be an integer number of steps, got {horizon!r}")
        if not 1 <= int(horizon) <= self.max_horizon:
            raise ValueError(f"horizon must be in 1..{self.max_horizon} steps, got {horizon}")
        return int(horizon)

    # ---------------------------------------------------------------------------------------------- roll-out
    def rollout(self, shape: Union[ShapeCode, np.ndarray], lin_vel: Any, ang_vel: Any, horizon: int = 60,
                position: Any = None, orientation: Any = None,
                observed: Union[Observed, Mapping[str, Any], None] = None, spread: bool = False) -> Trajectory:
        """Predict the motion after the object has velocities lin_vel / ang_vel at frame 0.

        Args:
            shape: a ShapeCode (encode) or a cloud (N, 3) in the table frame.
            lin_vel, ang_vel: (3,) m/s and rad/s, world frame.
            horizon: steps of dt to predict (1..max_horizon).
            position: (3,) start centre of mass (default: the code's centroid).
            orientation: (4,) start orientation x, y, z, w (default: identity, the pose the cloud was seen in).
            observed: optional states of frames 1..K (an Observed, or a mapping of its fields), kept as given.
            spread: also roll out the push weaker and stronger (physdyn_ros.spread, about 2 ms) for the Trajectory's
                spread; its radii are NaN where the checkpoint has no spread calibration (spread_problem says why).

        Returns:
            A Trajectory of horizon + 1 states (frame 0 the given start) with topple probabilities and novelty;
            with topple_fusion set and the code's points known (a cloud of the object as it is when the push
            starts), its whole-push topple probability is the fused one.
        """
        code = self._code(shape)
        horizon = self._check_horizon(horizon)
        v0 = _vector(lin_vel, 3, "lin_vel")
        w0 = _vector(ang_vel, 3, "ang_vel")
        p0 = code.centroid if position is None else _vector(position, 3, "position")
        q0 = np.array([0.0, 0.0, 0.0, 1.0]) if orientation is None else _quaternions(orientation, "orientation")[0]
        obs = self._check_observed(observed, horizon)
        fuse = None
        if self.topple_fusion is not None and code.points is not None and len(code.points) >= MIN_FUSION_POINTS:
            # the cloud is the object where the push starts (position and orientation only name that pose); the
            # velocities refer to the start position, the physics moves them to the solid's own centre of mass
            try:
                toppled = self.topple_fusion.physics.toppled(code.points, p0, v0, w0)
                fuse = lambda whole: self.topple_fusion.weights.fuse(whole, toppled[None])  # noqa: E731
            except ValueError:  # a cloud that encloses no solid (flat, a line): the model's probability stands
                fuse = None

        def run(v: np.ndarray, w: np.ndarray, seen: Optional[dict[str, np.ndarray]],
                f: Optional[Callable[[np.ndarray], np.ndarray]] = None) -> Trajectory:
            return self._run(code.feature[None], np.array([code.heading]), v[None], w[None], p0[None], q0[None],
                             horizon, seen, fuse=f)[0]

        traj = run(v0, w0, obs, fuse)
        if not spread:
            return traj
        lin, ang = perturbed_twists(v0, w0)
        others = []
        for k, (v, w) in enumerate(zip(lin, ang)):
            # observed states hand the push over to the model at their last one: perturb their velocities alike,
            # or the observation would wash the perturbation out (and the spread out with it)
            scaled = None if obs is None else {**obs, "lin_vels": obs["lin_vels"] * SPEEDS[k],
                                               "ang_vels": obs["ang_vels"] * SPEEDS[k]}
            others.append(run(v, w, scaled))
        sens = sensitivity(traj.positions[-1, :2], float(yaw_of(traj.orientations[-1])),
                           np.array([t.positions[-1, :2] for t in others]),
                           yaw_of(np.array([t.orientations[-1] for t in others])))
        cal = self.spread_calibration
        radius, turn = cal.radii(sens, DEFAULT_LEVEL) if cal is not None else (math.nan, math.nan)
        # the model's own probabilities of all three pushes (a fused one beside two unfused would measure the fusion)
        own = traj if fuse is None else run(v0, w0, obs)
        topple = float(np.std([own.topple_probability] + [t.topple_probability for t in others]))
        return replace(traj, spread=RestSpread(DEFAULT_LEVEL, radius, turn, topple, sens))

    def rollout_batch(self, shapes: Union[ShapeCode, np.ndarray, Sequence[Union[ShapeCode, np.ndarray]]],
                      lin_vels: Any, ang_vels: Any, horizon: int = 60, positions: Any = None,
                      orientations: Any = None, head_timing: bool = True) -> TrajectoryBatch:
        """Batched roll-outs: one shape with many velocities, or many shapes (a sequence of codes or clouds).

        Args:
            shapes: a ShapeCode or a cloud (N, 3), or a sequence of B of them (or a (B, N, 3) array of clouds).
            lin_vels, ang_vels: (B, 3) or (3,) (broadcast), world frame.
            horizon: steps of dt to predict (1..max_horizon).
            positions: (B, 3) or (3,) start centres of mass (default: the codes' centroids).
            orientations: (B, 4) or (4,) start orientations (default: identity).
            head_timing: for models with a topple head, True times the head's whole-push probability over a
                HEAD_TIMING_STEPS run, so a shorter horizon is that run's prefix (what `rollout` gives); False rolls
                out only `horizon` steps and reaches the whole-push probability by its last step (a planner wants
                the outcome of the push, not its timing, and a short search horizon then costs only its steps).

        Returns:
            A TrajectoryBatch of B trajectories of horizon + 1 states.
        """
        horizon = self._check_horizon(horizon)
        if isinstance(shapes, ShapeCode) or (isinstance(shapes, np.ndarray) and shapes.ndim == 2):
            codes = [self._code(shapes)]
        elif isinstance(shapes, (list, tuple)) or (isinstance(shapes, np.ndarray) and shapes.ndim == 3):
            checked: dict[int, ShapeCode] = {}  # a planner passes the same code many times: check it once
            codes = []
            for s in shapes:
                if isinstance(s, ShapeCode):
                    if id(s) not in checked:
                        checked[id(s)] = self._code(s)
                    codes.append(checked[id(s)])
                else:
                    codes.append(self._code(s))
            if not codes:
                raise ValueError("shapes is empty")
        else:
            raise ValueError("shapes must be a ShapeCode, a cloud (N, 3), or a sequence of them")
        v = _vectors(lin_vels, 3, "lin_vels")
        w = _vectors(ang_vels, 3, "ang_vels")
        sizes = {len(codes), len(v), len(w)} - {1}
        if len(sizes) > 1:
            raise ValueError(f"batch sizes disagree: {len(codes)} shapes, {len(v)} lin_vels, {len(w)} ang_vels")
        b = sizes.pop() if sizes else 1
        feats = np.stack([c.feature for c in codes])
        headings = np.array([c.heading for c in codes])
        centroids = np.stack([c.centroid for c in codes])
        p = np.broadcast_to(centroids, (b, 3)) if positions is None else _vectors(positions, 3, "positions", b)
        q = np.array([[0.0, 0.0, 0.0, 1.0]]) if orientations is None else _quaternions(orientations, "orientations", b)
        bc = lambda a: np.broadcast_to(a, (b,) + a.shape[1:])  # noqa: E731
        return self._run(bc(feats), np.broadcast_to(headings, (b,)), bc(v), bc(w), bc(p), bc(q), horizon, None,
                         head_timing)

    def _check_observed(self, observed: Any, horizon: int) -> Optional[dict[str, np.ndarray]]:
        if observed is None:
            return None
        get = (lambda k: getattr(observed, k)) if isinstance(observed, Observed) else (lambda k: observed[k])
        try:
            arrays = {k: np.asarray(get(k), dtype=np.float64)
                      for k in ("positions", "orientations", "lin_vels", "ang_vels")}
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"observed must hold positions, orientations, lin_vels, ang_vels: {exc}") from None
        k = len(arrays["positions"])
        for name, size in (("positions", 3), ("orientations", 4), ("lin_vels", 3), ("ang_vels", 3)):
            a = arrays[name]
            if a.shape != (k, size):
                raise ValueError(f"observed {name} must have shape ({k}, {size}), got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"observed {name} contains NaN or inf")
        if k >= horizon:
            raise ValueError(f"{k} observed states leave nothing to predict within horizon {horizon}")
        if k and np.any(np.linalg.norm(arrays["orientations"], axis=1) < 1e-9):
            raise ValueError("observed orientations must be non-zero quaternions")
        return arrays if k else None

    def _run(self, feats: np.ndarray, headings: np.ndarray, v0: np.ndarray, w0: np.ndarray, p0: np.ndarray,
             q0: np.ndarray, horizon: int, obs: Optional[dict[str, np.ndarray]],
             head_timing: bool = True, fuse: Optional[Callable[[np.ndarray], np.ndarray]] = None) -> TrajectoryBatch:
        """Roll out in frame C, then back to the table frame (all vectorised over the batch, numpy only: at batch 1
        the model runs a numpy kernel too, so a roll-out never pays torch's per-call overhead)."""
        wanted = horizon
        if self._topple is not None and head_timing:  # the head's probability is for the whole push: time it over
            horizon = max(horizon, HEAD_TIMING_STEPS)  # the full run
        h = headings[:, None]
        obs_v = obs_w = None
        k = 0
        if obs is not None:
            k = len(obs["positions"])
            obs_v = world_to_c(obs["lin_vels"][None], h)
            obs_w = world_to_c(obs["ang_vels"][None], h)
        vw = _yaw_rotate(np.stack([v0, w0], 1), -headings)  # world_to_c of both start velocities at once
        raw, xs, scales = self._model.rollout_arrays(np.asarray(feats[:, :self._dynamics_dim], np.float32), vw[:, 0],
                                                     vw[:, 1], horizon,
                                                     obs_v, obs_w, self.precision)
        # physical units as model.rollout computes them (float32 products), then float64 in the table frame:
        # per step d_pos, d_rot, vel, angvel as four 3-vectors, turned by the heading at once
        phys = np.concatenate([raw[..., 6:12] * scales["out"][6:12], xs[:, 1:] * scales["in"]], -1)
        vec = _yaw_rotate(phys.reshape(phys.shape[:2] + (4, 3)).astype(np.float64), headings)
        d_pos, d_rot = vec[:, :, 0], vec[:, :, 1]
        if obs is not None and k:  # observed frames keep their observed poses
            pos_seq = np.concatenate([p0[:1], obs["positions"]])
            q_obs = obs["orientations"] / np.linalg.norm(obs["orientations"], axis=1, keepdims=True)
            q_seq = np.concatenate([q0[:1], q_obs])
            d_pos[:, :k] = np.diff(pos_seq, axis=0)[None]
            d_rot[:, :k] = _rotation_increments(q_seq)[None]
        lin = np.concatenate([v0[:, None], vec[:, :, 2]], axis=1)
        ang = np.concatenate([w0[:, None], vec[:, :, 3]], axis=1)
        prob = np.concatenate([np.zeros((len(raw), 1)), 1.0 / (1.0 + np.exp(-raw[..., 12].astype(np.float64)))], axis=1)
        flat_unless_toppling(d_rot[:, k:], ang[:, k:], prob)  # observed steps keep their observed rotations
        novelty = None
        if self._topple is not None:
            head, novelty = self._topple.assess(feats[:, :self._dynamics_dim], feats[:, self._dynamics_dim:],
                                                vw[:, 0], vw[:, 1])
            prob = topple_with_head(prob, head, d_rot, ang, k, lambda rows, d: compose_rotations(q0[rows], d), fuse)
        settle(d_pos, d_rot, lin, ang, first=k + 1, dt=self.dt)
        p0 = np.asarray(p0, dtype=np.float64)[:, None]
        positions = np.concatenate([p0, p0 + np.cumsum(d_pos, axis=1)], axis=1)
        orientations = compose_rotations(q0, d_rot)
        n = wanted + 1  # a shorter horizon is the prefix of the longer roll-out
        return TrajectoryBatch(self.dt, positions[:, :n], orientations[:, :n], lin[:, :n], ang[:, :n],
                               consistent_topple(prob, orientations)[:, :n], novelty)


def _yaw_rotate(vec: np.ndarray, headings: np.ndarray) -> np.ndarray:
    """Vectors (B, ..., 3) turned about z by headings (B,): geometry.rotate_yaw's arithmetic, one heading per row."""
    shape = (len(headings),) + (1,) * (vec.ndim - 2)
    c, s = np.cos(headings).reshape(shape), np.sin(headings).reshape(shape)
    x, y = vec[..., 0], vec[..., 1]
    out = np.empty_like(vec)
    out[..., 0] = c * x - s * y
    out[..., 1] = s * x + c * y
    out[..., 2] = vec[..., 2]
    return out


def _rotation_increments(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (world axes, shortest) from each orientation q[t] to the next, (T, 4) -> (T-1, 3)."""
    return (Rotation.from_quat(q[1:]) * Rotation.from_quat(q[:-1]).inv()).as_rotvec()


# ------------------------------------------------------------------------------------------------------- clouds
def load_cloud(path: Union[str, os.PathLike]) -> np.ndarray:
    """(N, 3) points from .npy, .ply (ascii or binary, read by trimesh) or .xyz/.txt/.csv (first 3 columns)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"cloud file {path} does not exist")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        arr = np.load(path, allow_pickle=False)
    elif suffix == ".ply":
        arr = _read_ply(path)
    elif suffix in (".xyz", ".txt", ".csv", ".pts"):
        arr = np.loadtxt(path, delimiter="," if suffix == ".csv" else None, ndmin=2)[:, :3]
    else:
        raise ValueError(f"unsupported cloud file type {suffix!r} (use .npy, .ply, .xyz, .txt, .csv, .pts)")
    return check_cloud(np.asarray(arr, dtype=np.float64).reshape(-1, 3) if np.ndim(arr) == 1 else arr)


def _read_ply(path: Path) -> np.ndarray:
    """The x, y, z of a PLY file's vertices, read by trimesh (ascii and binary, any other vertex properties and
    elements: a mesh's vertices are its points). Raises ValueError naming the file and the problem."""
    import trimesh

    try:
        with open(path, "rb") as f:
            geom = trimesh.load(f, file_type="ply", process=False)
    except Exception as exc:  # trimesh's parser raises ValueError, KeyError ('x': no such property), IndexError...
        reason = f"no vertex property {exc}" if isinstance(exc, KeyError) else str(exc) or type(exc).__name__
        raise ValueError(f"{path}: cannot read a PLY point cloud (vertex x, y, z): {reason}") from None
    vertices = getattr(geom, "vertices", None)
    if vertices is None or len(vertices) == 0:
        raise ValueError(f"{path}: the PLY file holds no vertices")
    declared = geom.metadata.get("_ply_raw", {}).get("vertex", {}).get("length")
    if declared is not None and declared != len(vertices):
        raise ValueError(f"{path}: the PLY header declares {declared} vertices, the file holds {len(vertices)}")
    return np.asarray(vertices, dtype=np.float64)
