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
"""`physdyn evaluate`: a checkpoint (and baselines) on the test split, per category and overall.

Metrics (paper units: v cm/s, w rad/s, P cm, |theta| deg, axis 1 - cos), all on frames 0..H of each test
simulation (H = --horizon, 60 steps = 4 s by default), the cloud posed at frame 0:

* single-step: ground-truth velocities fed at every step; mean error of each per-step change
  (|d_v_hat - d_v| etc.; angle: ||d_theta_hat| - |d_theta||; axis: 1 - cos of the angle between the rotation
  axes where the true rotation exceeds 1 deg). All sequences, including toppling ones (as the paper), but
  only over steps where the object still moves (the original also averaged the rest padding, diluting errors).
* roll-out: the model's own velocities fed back from frame 0 (or after --steps-in observed frames). On
  sequences that never topple (as the paper): the same per-step change errors along the free-running
  trajectory, plus the accumulated pose error at every frame; final position error (cm) and final rotation
  error (deg) after H steps, median and p90.
* topple classification of whole trajectories (all sequences): predicted toppling if any roll-out step has
  p > 0.5, true if the simulation toppled; accuracy, precision, recall, F1.
Baselines on the same sequences: the MLP model (--mlp-checkpoint), analytic sliding, and pybullet
re-simulation of the convex hull with friction off by +-20 % (learn/baselines.py).
Outputs under --out: metrics.json, metrics.md (tables) and rollout_error.png (error vs time, as Figure 2).
"""
from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Optional

import numpy as np
import torch

from .. import geometry as geo
from . import frames
from .model import DynamicsModel
from .rules import HEAD_TIMING_STEPS, consistent_topple, flat_unless_toppling, settle, topple_with_head
from .support import DESCRIPTOR_POINTS, sequence_descriptors
from .windows import SimArrays, sequences

CM = 100.0
DEG = 180.0 / math.pi
AXIS_MIN_ANGLE = math.radians(1.0)  # axis errors only where the true rotation per step exceeds 1 deg


@dataclass
class Trajectories:
    """World-frame trajectories (B, H+1, *) of one method on the evaluated sequences."""

    pos: np.ndarray
    quat: np.ndarray
    lin_vel: np.ndarray
    ang_vel: np.ndarray
    topple_prob: Optional[np.ndarray] = None  # (B, H+1); None for methods that do not predict it


def _rows(traj: Trajectories, mask: np.ndarray) -> dict[str, Any]:
    """The fields of `traj` restricted to the sequences of `mask` (None stays None)."""
    return {k: (v[mask] if v is not None else None) for k, v in vars(traj).items()}


def ground_truth(sims: SimArrays, index: np.ndarray, horizon: int) -> Trajectories:
    sl = (index, slice(0, horizon + 1))
    return Trajectories(pos=sims.pos[sl].astype(np.float64), quat=sims.quat[sl].astype(np.float64),
                        lin_vel=sims.lin_vel[sl].astype(np.float64), ang_vel=sims.ang_vel[sl].astype(np.float64),
                        topple_prob=sims.toppled[sl].astype(np.float64))


def _batches(n: int, size: int) -> Iterator[slice]:
    for i in range(0, n, size):
        yield slice(i, min(n, i + size))


@torch.inference_mode()
def model_rollouts(model: DynamicsModel, sims: SimArrays, index: np.ndarray, horizon: int, steps_in: int = 1,
                   batch_size: int = 256, device: str | torch.device = "cpu", partial: float = 0.0,
                   noise: float = 0.0, plane_gap: float = 0.0) -> Trajectories:
    """Closed-loop roll-outs from frame 0; with steps_in = k, frames 1..k-1 are observed (fed and kept).
    partial / noise: that fraction of the clouds seen as one depth camera's view (fixed views, learn/views.py);
    plane_gap: the points within that many m of the table removed (windows.above_table)."""
    if steps_in < 1 or steps_in > horizon:
        raise ValueError(f"steps_in must be in 1..{horizon}, got {steps_in}")
    model.eval()
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("pos", "quat", "lin_vel", "ang_vel", "topple_prob")}
    wanted = horizon
    if model.topple is not None:  # as the Predictor: the head's timing over the full run, then the prefix
        horizon = max(horizon, HEAD_TIMING_STEPS)
    dense = DESCRIPTOR_POINTS if model.topple is not None else 0
    for sl in _batches(len(index), batch_size):
        idx = index[sl]
        seq = sequences(sims, wanted, model.cfg.num_points, idx, partial, noise, view_seed=sl.start,
                        plane_gap=plane_gap, desc_points=dense)
        k = steps_in - 1
        obs_v = seq["vel"][:, 1:1 + k].to(device) if k else None
        obs_w = seq["angvel"][:, 1:1 + k].to(device) if k else None
        feature = model.encode(seq["cloud"].to(device))
        rolled = model.rollout(feature, seq["vel"][:, 0].to(device), seq["angvel"][:, 0].to(device), horizon,
                               obs_v, obs_w)
        out = {kk: v.double().cpu().numpy() for kk, v in rolled.items()}
        d_pos, d_rot = out["d_pos"], out["d_rot"]
        if k:  # observed frames keep their true poses
            d_pos[:, :k] = seq["d_pos"][:, :k].double().numpy()
            d_rot[:, :k] = seq["d_rot"][:, :k].double().numpy()
        heading = seq["heading"].numpy()
        # what the Predictor outputs: the rest rule and topple probabilities consistent with the poses
        vel, angvel = out["vel"].copy(), out["angvel"].copy()
        prob = np.concatenate([np.zeros((len(idx), 1)), 1.0 / (1.0 + np.exp(-out["topple_logit"]))], axis=1)
        flat_unless_toppling(d_rot[:, k:], angvel[:, k:], prob)
        if model.topple is not None:  # the whole-push topple head, as the Predictor applies it
            com = model.com_estimate(feature).double().cpu().numpy()
            desc = sequence_descriptors(seq, com)
            head, _ = model.topple.assess(feature.cpu().numpy(), desc,
                                            seq["vel"][:, 0].numpy(), seq["angvel"][:, 0].numpy())
            p0, q0 = sims.pos[idx, 0], sims.quat[idx, 0]
            prob = topple_with_head(prob, head, d_rot, angvel, k, lambda rows, d: frames.integrate_in_world(
                heading[rows], p0[rows], q0[rows], d_pos[rows], d)[1])
        settle(d_pos, d_rot, vel, angvel, first=k + 1, dt=sims.dt)
        pos, quat = frames.integrate_in_world(heading, sims.pos[idx, 0], sims.quat[idx, 0], d_pos, d_rot)
        h = heading[:, None]
        parts["pos"].append(pos)
        parts["quat"].append(quat)
        parts["lin_vel"].append(frames.c_to_world(vel, h))
        parts["ang_vel"].append(frames.c_to_world(angvel, h))
        parts["topple_prob"].append(consistent_topple(prob, quat))
    return Trajectories(**{k: np.concatenate(v)[:, :wanted + 1] for k, v in parts.items()})


@torch.inference_mode()
def model_single_step(model: DynamicsModel, sims: SimArrays, index: np.ndarray, horizon: int,
                      batch_size: int = 256, device: str | torch.device = "cpu", partial: float = 0.0,
                      noise: float = 0.0, plane_gap: float = 0.0) -> dict[str, np.ndarray]:
    """Teacher-forced per-step change errors (B, H) in paper units (see change_errors)."""
    model.eval()
    parts: dict[str, list[np.ndarray]] = {}
    for sl in _batches(len(index), batch_size):
        seq = sequences(sims, horizon, model.cfg.num_points, index[sl], partial, noise, view_seed=sl.start,
                        plane_gap=plane_gap)
        feature = model.encode(seq["cloud"].to(device))
        raw = model.teacher_forced(feature, seq["vel"][:, :-1].to(device), seq["angvel"][:, :-1].to(device))
        pred = {k: v.double().cpu().numpy() for k, v in model.denormalize(raw).items()}
        true = {k: seq[k].double().numpy() for k in ("d_vel", "d_angvel", "d_pos", "d_rot")}
        for k, v in change_errors(pred, true).items():
            parts.setdefault(k, []).append(v)
    return {k: np.concatenate(v) for k, v in parts.items()}


def changes(traj: Trajectories) -> dict[str, np.ndarray]:
    """Per-step changes (B, H, 3) of a world trajectory (d_rot world-fixed, learn/frames.py)."""
    return frames.world_increments(traj.pos, traj.quat, traj.lin_vel, traj.ang_vel)


def change_errors(pred: dict[str, np.ndarray], true: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Errors (B, H) of per-step changes in paper units; axis error NaN where the true angle < 1 deg.

    Norms are rotation invariant, so world or frame-C changes give the same numbers.
    """
    n = np.linalg.norm
    ang_p, ang_t = n(pred["d_rot"], axis=-1), n(true["d_rot"], axis=-1)
    cos = np.sum(pred["d_rot"] * true["d_rot"], axis=-1) / np.maximum(ang_p * ang_t, 1e-12)
    axis = np.where(ang_t > AXIS_MIN_ANGLE, 1.0 - np.clip(cos, -1.0, 1.0), np.nan)
    return {"v": n(pred["d_vel"] - true["d_vel"], axis=-1) * CM,
            "w": n(pred["d_angvel"] - true["d_angvel"], axis=-1),
            "p": n(pred["d_pos"] - true["d_pos"], axis=-1) * CM,
            "angle": np.abs(ang_p - ang_t) * DEG, "axis": axis}


def pose_errors(pred: Trajectories, true: Trajectories) -> dict[str, np.ndarray]:
    """Accumulated errors (B, H+1): COM position (cm) and geodesic rotation (deg)."""
    return {"pos": np.linalg.norm(pred.pos - true.pos, axis=-1) * CM,
            "rot": geo.quat_angle_between(pred.quat, true.quat) * DEG}


def topple_scores(pred: np.ndarray, true: np.ndarray) -> dict[str, Any]:
    """Trajectory-level classification scores; None where undefined (no positives)."""
    pred, true = np.asarray(pred, bool), np.asarray(true, bool)
    tp, fp = int(np.sum(pred & true)), int(np.sum(pred & ~true))
    fn, tn = int(np.sum(~pred & true)), int(np.sum(~pred & ~true))
    precision = tp / (tp + fp) if tp + fp else None
    recall = tp / (tp + fn) if tp + fn else None
    f1 = ((2 * precision * recall / (precision + recall)) if precision and recall
          else (0.0 if tp + fp and tp + fn else None))
    return {"n": len(pred), "toppled": tp + fn, "accuracy": (tp + tn) / max(len(pred), 1), "precision": precision,
            "recall": recall, "f1": f1, "tp": tp, "fp": fp, "fn": fn, "tn": tn}


def calibration(prob: np.ndarray, true: np.ndarray, bins: int = 10) -> dict[str, Any]:
    """Brier score and reliability table (per probability bin: count, mean predicted, observed frequency) of
    whole-trajectory topple probabilities against what happened."""
    prob, true = np.asarray(prob, dtype=np.float64), np.asarray(true, dtype=bool)
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.digitize(prob, edges) - 1, 0, bins - 1)
    table = [{"bin": f"{edges[b]:.1f}-{edges[b + 1]:.1f}", "n": int(np.sum(which == b)),
              "predicted": float(prob[which == b].mean()) if np.any(which == b) else None,
              "observed": float(true[which == b].mean()) if np.any(which == b) else None} for b in range(bins)]
    return {"brier": float(np.mean((prob - true) ** 2)) if len(prob) else None, "reliability": table}


def _masked_mean(err: np.ndarray, mask: np.ndarray) -> Optional[float]:
    vals = err[mask & np.isfinite(err)]
    return float(vals.mean()) if vals.size else None


def _stats(values: np.ndarray) -> dict[str, Optional[float]]:
    values = values[np.isfinite(values)]
    if not values.size:
        return {"median": None, "p90": None, "mean": None}
    return {"median": float(np.median(values)), "p90": float(np.percentile(values, 90)), "mean": float(values.mean())}


def summarize_method(traj: Trajectories, gt: Trajectories, moving: np.ndarray, never_toppled: np.ndarray,
                     toppled: np.ndarray, single: Optional[dict[str, np.ndarray]] = None) -> dict[str, Any]:
    """All metrics of one method on one group of sequences."""
    res: dict[str, Any] = {"sequences": int(len(moving)), "rollout_sequences": int(never_toppled.sum())}
    if single is not None:
        res["single_step"] = {k: _masked_mean(v, moving) for k, v in single.items()}
        # as the original code averaged: every step of the horizon, the (zero-error) steps at rest included
        res["single_step_all_steps"] = {k: _masked_mean(v, np.ones_like(moving)) for k, v in single.items()}
    roll = change_errors(changes(traj), changes(gt))
    sel = moving & never_toppled[:, None]
    res["rollout_step"] = {k: _masked_mean(v, sel) for k, v in roll.items()}
    pe = pose_errors(traj, gt)
    res["final_pos_cm"] = _stats(pe["pos"][never_toppled, -1])
    res["final_rot_deg"] = _stats(pe["rot"][never_toppled, -1])
    res["pos_cm_vs_time_median"] = [float(x) for x in np.median(pe["pos"][never_toppled], axis=0)] \
        if never_toppled.any() else []
    res["rot_deg_vs_time_median"] = [float(x) for x in np.median(pe["rot"][never_toppled], axis=0)] \
        if never_toppled.any() else []
    if traj.topple_prob is not None:
        res["topple"] = topple_scores(np.any(traj.topple_prob[:, 1:] > 0.5, axis=1), toppled)
        res["topple"].update(calibration(traj.topple_prob[:, 1:].max(axis=1), toppled))
    return res


def evaluate_all(methods: dict[str, Trajectories], singles: dict[str, dict[str, np.ndarray]], gt: Trajectories,
                 sims: SimArrays, index: np.ndarray, horizon: int) -> dict[str, Any]:
    """{"overall": {method: metrics}, "per_category": {cat: {method: metrics}}}."""
    steps = np.arange(horizon)[None, :]
    moving = steps < (sims.length[index, None] - 1)  # transitions between recorded (not padded) frames
    toppled = sims.topple_index[index] >= 0
    cats = sims.category[index]
    groups = {"overall": np.ones(len(index), bool)}
    groups.update({f"category:{c}": cats == c for c in sorted(set(cats.tolist()))})
    out: dict[str, Any] = {"overall": {}, "per_category": {}}
    for gname, gmask in groups.items():
        if not gmask.any():
            continue
        sub_gt = Trajectories(**_rows(gt, gmask))
        res = {}
        for mname, traj in methods.items():
            sub = Trajectories(**_rows(traj, gmask))
            single = {k: v[gmask] for k, v in singles[mname].items()} if mname in singles else None
            res[mname] = summarize_method(sub, sub_gt, moving[gmask], ~toppled[gmask], toppled[gmask], single)
        if gname == "overall":
            out["overall"] = res
        else:
            out["per_category"][gname.split(":", 1)[1]] = res
    return out


# ----------------------------------------------------------------------------------------------- reporting
def _fmt(x: Any, digits: int = 3) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def _cloud_note(report: dict[str, Any]) -> str:
    """How the model's clouds were seen, where not whole (partial views, the table's slice removed)."""
    notes = []
    if report.get("partial_views"):
        notes.append(f"{report['partial_views']:.0%} of the model's clouds seen as one depth camera's view "
                     f"({1e3 * report.get('view_noise', 0.0):.0f} mm noise)")
    if report.get("plane_gap"):
        notes.append(f"the points within {1e3 * report['plane_gap']:.0f} mm of the table removed (--plane-gap)")
    return (" Clouds: " + "; ".join(notes) + ".") if notes else ""


def markdown_report(report: dict[str, Any]) -> str:
    lines = [f"# Evaluation: {report['checkpoint']}", "",
             f"data `{report['data']}` split `{report['split']}`, horizon {report['horizon']} steps "
             f"({report['horizon'] * report['dt']:.1f} s), steps in {report['steps_in']}. "
             "Units: v cm/s, w rad/s, P cm, |theta| deg, axis 1-cos." + _cloud_note(report), ""]
    groups = [("overall", report["results"]["overall"])] + sorted(report["results"]["per_category"].items())
    def single_step_table(key: str) -> list[str]:
        rows = ["| group | method | v | w | P | abs theta | axis |", "|---|---|---|---|---|---|---|"]
        for g, res in groups:
            rows += [f"| {g} | {m} | " + " | ".join(_fmt(r[key][k]) for k in ("v", "w", "p", "angle", "axis")) + " |"
                     for m, r in res.items() if key in r]
        return rows

    lines += ["## Single-step errors (all sequences)", ""] + single_step_table("single_step")
    lines += ["", "Averaged as the original code did (every step of the horizon, the steps at rest included; "
              "the table above averages the steps in motion only):", ""] + single_step_table("single_step_all_steps")
    lines += ["", "## Roll-out (sequences without toppling)", "",
              "| group | method | n | v | w | P | abs theta | axis | final P cm (median / p90) "
              "| final rot deg (median / p90) |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for g, res in groups:
        for m, r in res.items():
            s = r["rollout_step"]
            fp, fr = r["final_pos_cm"], r["final_rot_deg"]
            lines.append(f"| {g} | {m} | {r['rollout_sequences']} | "
                         + " | ".join(_fmt(s[k]) for k in ("v", "w", "p", "angle", "axis"))
                         + f" | {_fmt(fp['median'], 2)} / {_fmt(fp['p90'], 2)}"
                         + f" | {_fmt(fr['median'], 2)} / {_fmt(fr['p90'], 2)} |")
    lines += ["", "## Topple classification of whole trajectories (all sequences)", "",
              "| group | method | n | toppled | accuracy | precision | recall | F1 | Brier |",
              "|---|---|---|---|---|---|---|---|---|"]
    for g, res in groups:
        for m, r in res.items():
            if "topple" in r:
                t = r["topple"]
                lines.append(f"| {g} | {m} | {t['n']} | {t['toppled']} | {_fmt(t['accuracy'])} | "
                             f"{_fmt(t['precision'])} | {_fmt(t['recall'])} | {_fmt(t['f1'])} | "
                             f"{_fmt(t.get('brier'))} |")
    overall = report["results"]["overall"]
    for m, r in overall.items():
        if "topple" in r and r["topple"].get("reliability"):
            lines += ["", f"Reliability of the {m}'s topple probability (overall; max over the trajectory):", "",
                      "| probability | n | mean predicted | observed toppled |", "|---|---|---|---|"]
            lines += [f"| {b['bin']} | {b['n']} | {_fmt(b['predicted'])} | {_fmt(b['observed'])} |"
                      for b in r["topple"]["reliability"] if b["n"]]
    return "\n".join(lines) + "\n"


def plot_rollout_error(report: dict[str, Any], path: Path) -> None:
    """Median accumulated position and rotation error vs time per method (like the paper's Figure 2)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    dt = report["dt"]
    for name, r in report["results"]["overall"].items():
        if r["pos_cm_vs_time_median"]:
            t = np.arange(len(r["pos_cm_vs_time_median"])) * dt
            axes[0].plot(t, r["pos_cm_vs_time_median"], label=name)
            axes[1].plot(t, r["rot_deg_vs_time_median"], label=name)
    axes[0].set(xlabel="time (s)", ylabel="position error (cm), median", title="Roll-out position error")
    axes[1].set(xlabel="time (s)", ylabel="rotation error (deg), median", title="Roll-out rotation error")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ----------------------------------------------------------------------------------------------------- CLI
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--checkpoint", default=None, help="model checkpoint (default: the shipped model)")
    parser.add_argument("--data", required=True, help="dataset directory")
    parser.add_argument("--split", default="test", help="split to evaluate (default: test)")
    parser.add_argument("--categories", nargs="+", default=None, help="only these shape categories")
    parser.add_argument("--horizon", type=int, default=60, help="roll-out steps (default 60 = 4 s)")
    parser.add_argument("--steps-in", type=int, default=1,
                        help="observed frames fed before the roll-out runs free (paper: 1, 4, 6)")
    parser.add_argument("--mlp-checkpoint", default=None, help="the MLP baseline's checkpoint")
    parser.add_argument("--baselines", nargs="*", default=["analytic", "pybullet"],
                        choices=["analytic", "pybullet", "still"], help="non-learned baselines (default: analytic "
                        "and pybullet; still = the object stays where it is)")
    parser.add_argument("--partial", type=float, default=0.0, help="fraction of the clouds the model sees as one "
                        "depth camera's view (fixed random viewpoints above the table; default 0 = whole surface)")
    parser.add_argument("--view-noise", type=float, default=0.002, help="m of Gaussian noise on partial views")
    parser.add_argument("--plane-gap", type=float, default=0.0,
                        help="remove the points within this many m of the table from the model's clouds, as the "
                        "perception node removes the table plane (its plane_distance: 0.005; default 0: none)")
    parser.add_argument("--friction-error", type=float, default=0.2,
                        help="relative friction error of the pybullet baseline (default 0.2 = +-20%%)")
    parser.add_argument("--max-sequences", type=int, default=None, help="evaluate at most this many sequences")
    parser.add_argument("--out", required=True, help="output folder for metrics.json, metrics.md, rollout_error.png")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--batch-size", type=int, default=256)


def run(args: argparse.Namespace) -> int:
    from ..resources import DEFAULT_MODEL
    from .checkpoint import load_model
    from .windows import load_sims

    if not 0.0 <= args.partial <= 1.0 or args.view_noise < 0 or not 0.0 <= args.plane_gap < 0.1:
        raise ValueError(f"--partial must be in [0, 1], --view-noise >= 0 and --plane-gap in [0, 0.1) m, got "
                         f"{args.partial}, {args.view_noise}, {args.plane_gap}")
    if args.threads:
        torch.set_num_threads(args.threads)
    ckpt_path = Path(args.checkpoint) if args.checkpoint else DEFAULT_MODEL
    model, ckpt = load_model(ckpt_path, args.device)
    model.to(args.device)
    sims = load_sims(args.data, [args.split], categories=args.categories)
    if args.horizon < 1 or args.horizon + 1 > sims.num_frames:
        raise ValueError(f"--horizon must be in 1..{sims.num_frames - 1} for this dataset")
    index = np.arange(len(sims))
    if args.max_sequences is not None and args.max_sequences < len(index):
        index = np.linspace(0, len(sims) - 1, args.max_sequences).astype(np.int64)
    t0 = time.perf_counter()
    gt = ground_truth(sims, index, args.horizon)
    view = (args.partial, args.view_noise, args.plane_gap)
    methods: dict[str, Trajectories] = {"model": model_rollouts(model, sims, index, args.horizon, args.steps_in,
                                                               args.batch_size, args.device, *view)}
    singles = {"model": model_single_step(model, sims, index, args.horizon, args.batch_size, args.device, *view)}
    if "still" in args.baselines:  # the object stays where it is: the floor any predictor must beat
        methods["still"] = Trajectories(np.repeat(gt.pos[:, :1], args.horizon + 1, 1),
                                        np.repeat(gt.quat[:, :1], args.horizon + 1, 1),
                                        np.zeros_like(gt.lin_vel), np.zeros_like(gt.ang_vel))
    if args.mlp_checkpoint:
        mlp, _ = load_model(args.mlp_checkpoint, args.device)
        mlp.to(args.device)
        methods["mlp"] = model_rollouts(mlp, sims, index, args.horizon, args.steps_in, args.batch_size, args.device)
        singles["mlp"] = model_single_step(mlp, sims, index, args.horizon, args.batch_size, args.device)
    if "analytic" in args.baselines or "pybullet" in args.baselines:
        from .baselines import analytic_sliding, horizontal_radius, pybullet_resimulate

        pts = sims.points[sims.shape_index[index]]
        state0 = (sims.pos[index, 0], sims.quat[index, 0], sims.lin_vel[index, 0], sims.ang_vel[index, 0])
        if "analytic" in args.baselines:
            posed = frames.pose_cloud(pts, sims.scale[index], sims.quat[index, 0])
            a = analytic_sliding(*state0, sims.friction[index], horizontal_radius(posed), args.horizon, sims.dt)
            methods["analytic"] = Trajectories(a["pos"], a["quat"], a["lin_vel"], a["ang_vel"])
        if "pybullet" in args.baselines:
            for sign, name in ((-1, "pybullet_mu-"), (1, "pybullet_mu+")):
                mu = sims.friction[index] * (1.0 + sign * args.friction_error)
                r = pybullet_resimulate(pts, sims.scale[index], *state0, mu, args.horizon, sims.manifest)
                methods[f"{name}{int(round(args.friction_error * 100))}%"] = Trajectories(
                    r["pos"], r["quat"], r["lin_vel"], r["ang_vel"], r["toppled"].astype(np.float64))
    results = evaluate_all(methods, singles, gt, sims, index, args.horizon)
    report = {"checkpoint": str(ckpt_path), "model_id": ckpt["model_id"], "data": str(args.data),
              "partial_views": args.partial, "view_noise": args.view_noise, "plane_gap": args.plane_gap,
              "split": args.split, "categories": args.categories, "horizon": args.horizon, "dt": sims.dt,
              "steps_in": args.steps_in, "sequences": int(len(index)), "seconds": time.perf_counter() - t0,
              "results": results}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(report, indent=1))
    md = markdown_report(report)
    (out / "metrics.md").write_text(md)
    plot_rollout_error(report, out / "rollout_error.png")
    print(md)
    print(f"wrote {out / 'metrics.json'}, {out / 'metrics.md'}, {out / 'rollout_error.png'}")
    return 0
