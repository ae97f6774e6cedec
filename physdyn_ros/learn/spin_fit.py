"""Fitting the spin head (learn/spin.py) on a trained model's frozen roll-outs: `physdyn fit-spin`.

For each training push that does not topple (a fraction seen as one depth camera's partial view), the model's
roll-out (physdyn evaluate's, 4 s) is run with each step's change of spin about z scaled by every factor of a
log-spaced grid (K_MIN..K_MAX, 1 among them), giving that push's final rotation and position errors as functions
of k. The head (shape feature + initial twist -> log k) is trained to minimise the mean log(1 + rotation error in
deg) + w log(1 + position error in cm) (--position-weight w), read off each push's own curves at its predicted k
(linear in log k between the grid's factors): it learns where the network stops spins too soon or too late
without a loss term on the spin. The epoch of lowest validation loss is kept; the validation figures are read
off the validation pushes' curves (bench/spin_budget.py and physdyn evaluate roll the head out).
"""
from __future__ import annotations

import argparse
import copy
import time
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np
import torch

from .. import geometry as geo
from .evaluate import _batches, model_rollouts
from .model import DynamicsModel
from .spin import K_MAX, K_MIN, SpinHead
from .support import descriptor_points
from .topple_fit import _shares
from .windows import SimArrays, sequences

HORIZON = 60
#: 13 log-spaced factors K_MIN ... K_MAX (0.25 ... 2), 1 at index 8
GRID = np.exp(np.linspace(np.log(K_MIN), np.log(K_MAX), 13))
BATCH = 256  # model_rollouts' batch size: the partial views' seeds follow its batches


def final_errors(model: DynamicsModel, sims: SimArrays, index: np.ndarray, scale: Optional[np.ndarray],
                 partial: float = 0.0, noise: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """(n,) final rotation (deg) and position (cm) errors after HORIZON steps of physdyn evaluate's roll-outs with
    spin_scale."""
    traj = model_rollouts(model, sims, index, HORIZON, batch_size=BATCH, partial=partial, noise=noise,
                          spin_scale=scale)
    rot = np.degrees(geo.quat_angle_between(traj.quat[:, HORIZON], sims.quat[index, HORIZON]))
    return rot, 100.0 * np.linalg.norm(traj.pos[:, HORIZON] - sims.pos[index, HORIZON], axis=-1)


def rotation_errors(model: DynamicsModel, sims: SimArrays, index: np.ndarray, scale: Optional[np.ndarray],
                    partial: float = 0.0, noise: float = 0.002) -> np.ndarray:
    """(n,) final rotation error (deg) of final_errors."""
    return final_errors(model, sims, index, scale, partial, noise)[0]


def error_curves(model: DynamicsModel, sims: SimArrays, index: np.ndarray, partial: float = 0.0,
                 noise: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """(n, len(GRID)) final rotation (deg) and position (cm) errors of each push at every grid factor."""
    pairs = [final_errors(model, sims, index, np.full(len(index), k), partial, noise) for k in GRID]
    return np.stack([p[0] for p in pairs], 1), np.stack([p[1] for p in pairs], 1)


@torch.inference_mode()
def head_inputs(model: DynamicsModel, head: SpinHead, sims: SimArrays, index: np.ndarray, partial: float = 0.0,
                noise: float = 0.002) -> np.ndarray:
    """(n, in_dim) the head's raw inputs from the clouds model_rollouts sees (the same batches and view seeds)."""
    dense = descriptor_points(model.topple.inputs) if model.topple is not None else 0
    rows = []
    for sl in _batches(len(index), BATCH):
        seq = sequences(sims, HORIZON, model.cfg.num_points, index[sl], partial, noise, view_seed=sl.start,
                        desc_points=dense)
        feature = model.encode(seq["cloud"]).numpy()
        rows.append(head.raw_inputs(feature, seq["vel"][:, 0].numpy(), seq["angvel"][:, 0].numpy()))
    return np.concatenate(rows)


def _pushes(model: DynamicsModel, head: SpinHead, sims: SimArrays, n: int, partial: float, noise: float,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(inputs, rotation and position error curves) of n pushes of `sims` that do not topple, a `partial` fraction
    seen as partial views."""
    pool = np.flatnonzero(sims.topple_index < 0)
    index = np.sort(rng.choice(pool, min(n, len(pool)), replace=False))
    parted = np.zeros(len(index), dtype=bool)
    parted[rng.permutation(len(index))[:int(round(partial * len(index)))]] = True
    xs, rots, poss = [], [], []
    for rows, view in ((index[~parted], 0.0), (index[parted], 1.0)):
        if len(rows):
            xs.append(head_inputs(model, head, sims, rows, view, noise))
            rot, pos = error_curves(model, sims, rows, view, noise)
            rots.append(rot)
            poss.append(pos)
    return np.concatenate(xs), np.concatenate(rots), np.concatenate(poss)


def _read(log_k: torch.Tensor, curves: torch.Tensor) -> torch.Tensor:
    """Each row's loss curve read at its log k, linear between the grid's factors (B,)."""
    lg = np.log(GRID)
    step = float(lg[1] - lg[0])
    pos = (log_k - float(lg[0])) / step
    j = pos.floor().long().clamp(0, len(GRID) - 2)
    a = pos - j
    return (1 - a) * curves.gather(1, j[:, None])[:, 0] + a * curves.gather(1, j[:, None] + 1)[:, 0]


def _train(head: SpinHead, x: np.ndarray, curves: np.ndarray, xv: np.ndarray, cv: np.ndarray, epochs: int,
           lr: float, weight_decay: float, seed: int, log: Optional[Callable[[str], None]]) -> dict[str, Any]:
    torch.manual_seed(seed)
    with torch.no_grad():
        head.mean.copy_(torch.from_numpy(x.mean(0)))
        head.std.copy_(torch.from_numpy(x.std(0) + 1e-6))
    head.reset_output()
    xt, yt = torch.from_numpy(x), torch.from_numpy(curves.astype(np.float32))
    xvt, yvt = torch.from_numpy(xv), torch.from_numpy(cv.astype(np.float32))
    opt = torch.optim.Adam(head.parameters(), lr, weight_decay=weight_decay)

    def val_loss() -> float:
        with torch.no_grad():
            return float(_read(head.log_factor(xvt), yvt).mean())

    best = (val_loss(), 0, copy.deepcopy(head.state_dict()))  # epoch 0: k = 1
    first = best[0]
    for epoch in range(1, epochs + 1):
        head.train()
        for rows in torch.randperm(len(xt)).split(256):
            loss = _read(head.log_factor(xt[rows]), yt[rows]).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        head.eval()
        v = val_loss()
        if v < best[0]:
            best = (v, epoch, copy.deepcopy(head.state_dict()))
    head.load_state_dict(best[2])
    if log:
        log(f"spin head: validation loss {first:.4f} at k = 1 -> {best[0]:.4f} (epoch {best[1]})")
    return {"val_loss_k1": round(first, 4), "val_loss": round(best[0], 4), "best_epoch": best[1]}


def fit_spin_head(model: DynamicsModel, train: SimArrays | Sequence[SimArrays], val: SimArrays | Sequence[SimArrays],
                  *, max_train: int = 6000, max_val: int = 1000, partial: float = 0.5, noise: float = 0.002,
                  epochs: int = 60, lr: float = 1e-3, weight_decay: float = 1e-4, seed: int = 0,
                  position_weight: float = 0.0,
                  log: Optional[Callable[[str], None]] = print) -> dict[str, Any]:
    """Fit model.spin (a SpinHead) in place; the rest of the model is frozen. Returns the validation figures.
    train, val: one dataset's splits or several datasets' (pushes drawn in proportion to their sizes). The loss
    is the mean log(1 + final rotation error in deg) + position_weight log(1 + final position error in cm): the
    spin and the slide share the prior's friction, so a longer spin also slides further."""
    if position_weight < 0:
        raise ValueError(f"position_weight must be >= 0, got {position_weight}")
    head = model.spin
    if not isinstance(head, SpinHead):
        raise ValueError("the model has no spin head (model.spin_head: true)")
    if model.cfg.prior == "none":
        raise ValueError("the spin head needs a model with a prior (model.prior)")
    t0 = time.time()
    model.eval()
    head.reset_output()  # the curves are the network's own (k = 1 is the model without a head)
    trains = [train] if isinstance(train, SimArrays) else list(train)
    vals = [val] if isinstance(val, SimArrays) else list(val)
    rng = np.random.default_rng(seed)

    def draw(sets: list[SimArrays], total: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        sizes = [int((s.topple_index < 0).sum()) for s in sets]
        parts = [_pushes(model, head, s, n, partial, noise, rng) for s, n in zip(sets, _shares(sizes, total)) if n]
        if not parts:
            raise ValueError("no pushes that do not topple to fit the spin head on")
        return tuple(np.concatenate([p[j] for p in parts]) for j in range(3))  # type: ignore[return-value]

    def loss_curves(rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
        return np.log1p(rot) + position_weight * np.log1p(pos)

    x, rot, pos = draw(trains, max_train)
    xv, rot_v, pos_v = draw(vals, max_val)
    curves, cv = loss_curves(rot, pos), loss_curves(rot_v, pos_v)
    if log:
        log(f"spin head: {len(x)} training and {len(xv)} validation pushes, {len(GRID)} roll-outs each in "
            f"{time.time() - t0:.0f} s")
    result = _train(head, x, curves, xv, cv, epochs, lr, weight_decay, seed, log)
    with torch.no_grad():
        k = np.exp(head.log_factor(torch.from_numpy(xv)).numpy())
    one = int(np.argmin(np.abs(GRID - 1.0)))
    # the validation pushes' curves read at the head's k; real roll-outs with the head are bench/spin_budget.py's
    # and physdyn evaluate's
    def read(curve: np.ndarray) -> np.ndarray:
        return np.array([np.interp(np.log(kk), np.log(GRID), row) for kk, row in zip(k, curve)])

    rot_k, pos_k = read(rot_v), read(pos_v)
    result.update({"train_pushes": int(len(x)), "val_pushes": int(len(xv)), "partial": partial,
                   "position_weight": position_weight, "k_median": round(float(np.median(k)), 3),
                   "k_p10_p90": [round(float(np.percentile(k, 10)), 3), round(float(np.percentile(k, 90)), 3)],
                   "val_rotation_median_deg_k1": round(float(np.median(rot_v[:, one])), 3),
                   "val_rotation_median_deg": round(float(np.median(rot_k)), 3),
                   "val_rotation_p90_deg_k1": round(float(np.percentile(rot_v[:, one], 90)), 2),
                   "val_rotation_p90_deg": round(float(np.percentile(rot_k, 90)), 2),
                   "val_position_p90_cm_k1": round(float(np.percentile(pos_v[:, one], 90)), 3),
                   "val_position_p90_cm": round(float(np.percentile(pos_k, 90)), 3),
                   "seconds": round(time.time() - t0, 1)})
    if log:
        log(f"spin head: validation final rotation median {result['val_rotation_median_deg_k1']}° -> "
            f"{result['val_rotation_median_deg']}°, p90 {result['val_rotation_p90_deg_k1']}° -> "
            f"{result['val_rotation_p90_deg']}°, position p90 {result['val_position_p90_cm_k1']} -> "
            f"{result['val_position_p90_cm']} cm (read off the curves; k median {result['k_median']}, p10-p90 "
            f"{result['k_p10_p90']}), "
            f"{result['seconds']} s")
    return result


# --------------------------------------------------------------------------------------------- physdyn fit-spin
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = ("Fit the spin head of a trained checkpoint (a per-push factor on the roll-out's change of "
                          "spin, from the frozen shape feature and the initial twist) and write a new inference "
                          "checkpoint (a new model_id).")
    parser.add_argument("--checkpoint", required=True, help="trained checkpoint (its dynamics and topple head stay)")
    parser.add_argument("--data", required=True, action="append",
                        help="dataset directory (its train and val splits); repeat to fit on several datasets")
    parser.add_argument("--out", required=True, help="the new checkpoint file")
    parser.add_argument("--max-train", type=int, default=6000,
                        help="training pushes that do not topple (default 6000; 13 roll-outs each)")
    parser.add_argument("--max-val", type=int, default=1000, help="validation pushes (default 1000)")
    parser.add_argument("--partial", type=float, default=0.5,
                        help="fraction seen as one depth camera's partial view (default 0.5)")
    parser.add_argument("--epochs", type=int, default=60, help="epochs (default 60; the best by validation is kept)")
    parser.add_argument("--position-weight", type=float, default=1.0,
                        help="weight of log(1 + final position error, cm) beside log(1 + final rotation error, deg) "
                             "in the loss (default 1; 0: rotation only)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")


def run(args: argparse.Namespace) -> int:
    from .checkpoint import load_checkpoint, save_checkpoint
    from .model import ModelConfig
    from .windows import load_sims

    if args.threads > 0:
        torch.set_num_threads(args.threads)
    if args.max_train < 20 or args.max_val < 10 or args.epochs < 1 or not 0.0 <= args.partial <= 1.0:
        raise ValueError("--max-train must be >= 20, --max-val >= 10, --epochs >= 1, --partial in [0, 1]")
    ckpt = load_checkpoint(args.checkpoint)
    config = copy.deepcopy(ckpt["config"])
    config["model"] = dict(config["model"], spin_head=True)
    model = DynamicsModel(ModelConfig.from_dict(config["model"]))
    state = {k: v for k, v in ckpt["model"].items() if not k.startswith("spin.")}  # refit an existing head
    missing = [k for k in model.load_state_dict(state, strict=False).missing_keys if not k.startswith("spin.")]
    if missing:
        raise ValueError(f"{args.checkpoint}: weights do not fit the model config (missing {missing[:3]})")
    datas = [args.data] if isinstance(args.data, str) else list(args.data)
    result = fit_spin_head(model, [load_sims(d, ["train"]) for d in datas], [load_sims(d, ["val"]) for d in datas],
                           max_train=args.max_train, max_val=args.max_val, partial=args.partial, epochs=args.epochs,
                           seed=args.seed, position_weight=float(getattr(args, "position_weight", 1.0)))
    resolved = [str(Path(d).resolve()) for d in datas]
    config["spin_fit"] = {"source": ckpt["model_id"], "data": resolved[0] if len(resolved) == 1 else resolved,
                          "max_train": args.max_train, "max_val": args.max_val, "partial": args.partial,
                          "epochs": args.epochs, "seed": args.seed,
                          "position_weight": float(getattr(args, "position_weight", 1.0)), "validation": result}
    model_id = save_checkpoint(args.out, model=model.eval(), config=config, dataset=ckpt.get("dataset", {}),
                               progress=ckpt.get("progress"), include_rng=False)
    print(f"wrote {args.out} (model_id {model_id}; dynamics of {ckpt['model_id']})")
    return 0
