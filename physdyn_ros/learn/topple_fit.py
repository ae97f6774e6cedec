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
"""Fitting the whole-push topple head (learn/topple.py) on a trained model's frozen shape features.

Inputs come from whole simulations (frame 0: the cloud, the initial twist; label: the simulation toppled at
some frame), with a fraction of the clouds seen as one depth camera's partial view, as in training. Each
ensemble member is trained with its own seed and keeps the epoch of lowest validation loss.
"""
from __future__ import annotations

import argparse
import copy
import time
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np
import torch

from .evaluate import _fmt, calibration, topple_scores
from .model import DynamicsModel
from .support import DESCRIPTOR_POINTS, push_quantities, sequence_descriptors
from .topple import ToppleHead, apply_calibration
from .windows import SimArrays, sequences


@torch.inference_mode()
def topple_inputs(model: DynamicsModel, sims: SimArrays, index: np.ndarray, partial: float = 0.0,
                  noise: float = 0.002, view_seed: int = 0, batch_size: int = 256) -> dict[str, np.ndarray]:
    """feature (B, F), desc (B, D), push (B, E), label (B,), category (B,) of simulations `index` (frame 0,
    C frame)."""
    parts: dict[str, list[np.ndarray]] = {"feature": [], "desc": [], "push": [], "label": [], "category": []}
    for start in range(0, len(index), batch_size):
        idx = index[start:start + batch_size]
        seq = sequences(sims, 1, model.cfg.num_points, idx, partial, noise, view_seed=view_seed + start,
                        desc_points=DESCRIPTOR_POINTS)
        feature = model.encode(seq["cloud"])
        desc = sequence_descriptors(seq, model.com_estimate(feature).numpy())
        parts["feature"].append(feature.numpy())
        parts["desc"].append(desc)
        parts["push"].append(push_quantities(desc, seq["vel"][:, 0].numpy(), seq["angvel"][:, 0].numpy()))
        parts["label"].append((sims.topple_index[idx] >= 0).astype(np.float32))
        parts["category"].append(np.asarray(sims.category[idx]).astype(str))
    return {k: np.concatenate(v) for k, v in parts.items()}


def _join(*sets: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: np.concatenate([s[k] for s in sets]) for k in sets[0]}


def scores(prob: np.ndarray, label: np.ndarray, threshold: float = 0.5) -> dict[str, Any]:
    """physdyn evaluate's topple scores at `threshold` (F1, precision, recall; None where undefined) with the
    Brier score and reliability table."""
    true = label > 0.5
    return {**topple_scores(prob > threshold, true), **calibration(prob, true)}


def _raw(head: ToppleHead, d: dict[str, np.ndarray]) -> torch.Tensor:
    with torch.no_grad():
        return head.raw_inputs(torch.from_numpy(d["feature"]).float(), torch.from_numpy(d["desc"]).float(),
                               torch.from_numpy(d["push"]).float())


def _train_members(head: ToppleHead, x: torch.Tensor, y: torch.Tensor, xv: torch.Tensor, yv: torch.Tensor, *,
                   epochs: int, batch_size: int, lr: float, weight_decay: float, seed: int,
                   log: Optional[Callable[[str], None]], feature_dropout: float = 0.0) -> None:
    """Standardisation and novelty from x, then each member from its own seed, keeping its epoch of lowest
    validation loss on (xv, yv). feature_dropout: the chance that a training push's whole shape feature (the
    encoder's numbers and the dynamics network's cloud-geometry inputs) is replaced by its mean (0 after
    standardisation), so that the head also decides from the support descriptors and push quantities alone:
    they carry over to shapes the encoder has never seen, the feature less so."""
    head.mean.copy_(x.mean(0))
    head.std.copy_(x.std(0).clamp_min(1e-6))
    head.set_novelty(x)
    loss_fn = torch.nn.functional.binary_cross_entropy_with_logits
    zx, zv = (x - head.mean) / head.std, (xv - head.mean) / head.std
    for k, member in enumerate(head.members):
        gen = torch.Generator().manual_seed(seed * 1000 + k)
        for layer in member.modules():
            if isinstance(layer, torch.nn.Linear):
                torch.nn.init.kaiming_uniform_(layer.weight, a=5 ** 0.5, generator=gen)
                torch.nn.init.zeros_(layer.bias)
        opt = torch.optim.Adam(member.parameters(), lr=lr, weight_decay=weight_decay)
        best, best_state = float("inf"), None
        for _ in range(epochs):
            member.train()
            perm = torch.randperm(len(zx), generator=gen)
            for i in range(0, len(zx), batch_size):
                b = perm[i:i + batch_size]
                zb = zx[b]
                if feature_dropout > 0.0:
                    keep = (torch.rand(len(b), 1, generator=gen) >= feature_dropout).to(zb.dtype)
                    zb = torch.cat([zb[:, :head.feature_dim] * keep, zb[:, head.feature_dim:]], dim=1)
                loss = loss_fn(member(zb)[:, 0], y[b])
                opt.zero_grad()
                loss.backward()
                opt.step()
            member.eval()
            with torch.no_grad():
                vloss = float(loss_fn(member(zv)[:, 0], yv))
            if vloss < best:
                best, best_state = vloss, {kk: v.clone() for kk, v in member.state_dict().items()}
        assert best_state is not None
        member.load_state_dict(best_state)
        if log:
            log(f"topple head member {k + 1}/{len(head.members)}: validation loss {best:.4f}")


def _mean_prob(head: ToppleHead, x: torch.Tensor) -> np.ndarray:
    """The members' mean probability, before the calibration."""
    with torch.no_grad():
        return torch.sigmoid(head.member_logits(x)).mean(0).numpy()


def split_families(categories: np.ndarray, folds: int, seed: int = 0) -> list[list[str]]:
    """The training families dealt into `folds` groups (shuffled by `seed`, sorted within a fold)."""
    names = sorted(set(str(c) for c in categories))
    if not 2 <= folds <= len(names):
        raise ValueError(f"family folds must be in 2..{len(names)} (the training data has {len(names)} families: "
                         f"{names}), got {folds}")
    order = np.random.default_rng(seed).permutation(len(names))
    return [sorted(names[i] for i in order[k::folds]) for k in range(folds)]


def cross_validate(head: ToppleHead, data: dict[str, np.ndarray], vdata: dict[str, np.ndarray], folds: int, *,
                   seed: int = 0, log: Optional[Callable[[str], None]] = print,
                   **train: Any) -> tuple[np.ndarray, np.ndarray]:
    """Leave-families-out: for each fold of families, a copy of `head` trained on the other families (early
    stopping on their validation pushes) predicts the fold's training pushes. Returns (the members' mean
    probability, label) of every training push, each predicted by a head that never saw its family."""
    prob = np.full(len(data["label"]), np.nan)
    for k, fold in enumerate(split_families(data["category"], folds, seed)):
        out, vout = np.isin(data["category"], fold), np.isin(vdata["category"], fold)
        fold_head = copy.deepcopy(head)
        pick = {key: v[~out] for key, v in data.items()}
        vpick = {key: v[~vout] for key, v in vdata.items()}
        _train_members(fold_head, _raw(fold_head, pick), torch.from_numpy(pick["label"]), _raw(fold_head, vpick),
                       torch.from_numpy(vpick["label"]), seed=seed + 100 * (k + 1), log=None, **train)
        prob[out] = _mean_prob(fold_head, _raw(fold_head, {key: v[out] for key, v in data.items()}))
        if log:
            s = scores(prob[out], data["label"][out])
            log(f"family fold {k + 1}/{folds} {fold}: {int(out.sum())} pushes, out-of-family F1 {_fmt(s['f1'])} "
                f"(precision {_fmt(s['precision'])}, recall {_fmt(s['recall'])}), Brier {_fmt(s['brier'], 4)}")
    return prob, data["label"]


def fit_calibration(prob: np.ndarray, label: np.ndarray, iterations: int = 50) -> tuple[float, float]:
    """(scale, shift) of the logistic regression of `label` on logit(prob) (Platt scaling), by Newton steps with
    a small ridge toward the identity; raises ValueError when the labels are all of one kind."""
    p = np.clip(np.asarray(prob, dtype=np.float64), 1e-6, 1.0 - 1e-6)
    y = np.asarray(label, dtype=np.float64) > 0.5
    if y.all() or not y.any():
        raise ValueError("calibration needs pushes that toppled and pushes that did not")
    x = np.c_[np.log(p / (1.0 - p)), np.ones(len(p))]
    theta, prior, ridge = np.array([1.0, 0.0]), np.array([1.0, 0.0]), 1e-3 * len(p)
    for _ in range(iterations):
        q = 1.0 / (1.0 + np.exp(-(x @ theta)))
        grad = x.T @ (q - y) + ridge * (theta - prior)
        hess = (x * (q * (1.0 - q))[:, None]).T @ x + ridge * np.eye(2)
        step = np.linalg.solve(hess, grad)
        theta = theta - step
        if np.abs(step).max() < 1e-9:
            break
    return float(theta[0]), float(theta[1])


def _pushes(model: DynamicsModel, sims: SimArrays, n: int, partial: float, noise: float, rng: np.random.Generator,
            seed: int) -> dict[str, np.ndarray]:
    """Inputs of n simulations drawn from `sims`, a `partial` fraction of them seen as one camera's view."""
    index = np.sort(rng.choice(len(sims), n, replace=False))
    parted = rng.permutation(n)[:int(round(partial * n))]
    full_rows = np.setdiff1d(np.arange(n), parted)
    parts = [(index[full_rows], 0.0, seed), (np.sort(index[parted]), 1.0, seed + 1)]
    return _join(*(topple_inputs(model, sims, idx, view, noise, s) for idx, view, s in parts if len(idx)))


def _shares(sizes: Sequence[int], total: int) -> list[int]:
    """`total` dealt over datasets of `sizes` in proportion (largest remainders), none above its size."""
    total = min(total, int(sum(sizes)))
    exact = np.asarray(sizes, dtype=np.float64) * total / max(sum(sizes), 1)
    share = np.floor(exact).astype(int)
    for k in np.argsort(-(exact - share))[:total - int(share.sum())]:
        share[k] += 1
    return [int(min(s, n)) for s, n in zip(share, sizes)]


def fit_topple_head(model: DynamicsModel, train: SimArrays | Sequence[SimArrays],
                    val: SimArrays | Sequence[SimArrays], *, max_train: int = 24000,
                    partial: float = 1.0 / 3.0, noise: float = 0.002, epochs: int = 120, batch_size: int = 512,
                    lr: float = 3e-3, weight_decay: float = 1e-3, seed: int = 0, family_folds: int = 0,
                    feature_dropout: float = 0.0, log: Optional[Callable[[str], None]] = print) -> dict[str, Any]:
    """Fit model.topple (a ToppleHead) in place; returns validation scores. The rest of the model is frozen.

    train, val: one dataset's splits or several datasets' (their training pushes drawn in proportion to their
    sizes, max_train in all; every validation push).

    family_folds > 1: before the final fit, leave-families-out cross-validation (cross_validate) gives every
    training push a probability from a head that never saw its family; the head's calibration is the Platt
    scaling fitted on those (a head meets new families in use). The result then also holds the out-of-family
    scores before ("out_of_family_raw") and after ("out_of_family") the calibration (the latter in-sample for
    its two numbers) and the calibration itself.
    """
    head = model.topple
    if not isinstance(head, ToppleHead):
        raise ValueError("the model has no topple head (model.topple_head: true)")
    t0 = time.time()
    trains = [train] if isinstance(train, SimArrays) else list(train)
    vals = [val] if isinstance(val, SimArrays) else list(val)
    rng = np.random.default_rng(seed)
    model.eval()
    # dataset k's view seeds are offset by 10 k: one dataset draws exactly as before several were allowed
    data = _join(*(_pushes(model, sims, n, partial, noise, rng, seed + 10 * k)
                   for k, (sims, n) in enumerate(zip(trains, _shares([len(t) for t in trains], max_train))) if n))
    vdata = _join(*(_join(topple_inputs(model, v, np.arange(len(v)), 0.0, noise, seed + 10 * k + 2),
                          topple_inputs(model, v, np.arange(len(v)), 1.0, noise, seed + 10 * k + 3))
                    for k, v in enumerate(vals)))
    if log:
        log(f"topple head: {len(data['label'])} training pushes ({data['label'].mean():.1%} toppled), "
            f"{len(vdata['label'])} validation, inputs in {time.time() - t0:.0f} s")
    train_args: dict[str, Any] = {"epochs": epochs, "batch_size": batch_size, "lr": lr, "weight_decay": weight_decay,
                                  "feature_dropout": feature_dropout}
    extra: dict[str, Any] = {}
    head.calibration.copy_(torch.tensor([1.0, 0.0]))
    if family_folds:
        cv_prob, cv_label = cross_validate(head, data, vdata, family_folds, seed=seed, log=log, **train_args)
        ab = fit_calibration(cv_prob, cv_label)
        calibrated = apply_calibration(cv_prob, *ab)
        extra = {"calibration": [round(ab[0], 4), round(ab[1], 4)], "family_folds": family_folds,
                 "out_of_family_raw": scores(cv_prob, cv_label),
                 "out_of_family": scores(calibrated, cv_label),
                 # each family predicted by heads that never saw it: a leave-families-out table per family
                 "out_of_family_by_family": {
                     str(c): {k: v for k, v in scores(calibrated[data["category"] == c],
                                                      cv_label[data["category"] == c]).items()
                              if k in ("n", "toppled", "precision", "recall", "f1", "brier")}
                     for c in sorted(set(data["category"].tolist()))}}
        if log:
            before, after = extra["out_of_family_raw"], extra["out_of_family"]
            log(f"calibration for new families: scale {ab[0]:.3f}, shift {ab[1]:.3f}; out-of-family F1 "
                f"{_fmt(before['f1'])} -> {_fmt(after['f1'])}, Brier {_fmt(before['brier'], 4)} -> "
                f"{_fmt(after['brier'], 4)}")
            log("out-of-family F1 by family: " + ", ".join(
                f"{c} {_fmt(v['f1'])}" for c, v in extra["out_of_family_by_family"].items()))
    _train_members(head, _raw(head, data), torch.from_numpy(data["label"]), _raw(head, vdata),
                   torch.from_numpy(vdata["label"]), seed=seed, log=log, **train_args)
    if family_folds:
        head.calibration.copy_(torch.tensor(extra["calibration"], dtype=torch.float32))
    with torch.no_grad():
        prob = head.calibrated(torch.from_numpy(_mean_prob(head, _raw(head, vdata)))).numpy()
    result = {**scores(prob, vdata["label"]), **extra}
    result["seconds"] = round(time.time() - t0, 1)
    result["train_pushes"] = int(len(data["label"]))
    if log:
        f1, precision, recall = (_fmt(result[k]) for k in ("f1", "precision", "recall"))
        log(f"topple head: validation F1 {f1} (precision {precision}, recall {recall}), Brier "
            f"{_fmt(result['brier'], 4)}, {result['seconds']} s")
    return result


# ------------------------------------------------------------------------------------------ physdyn fit-topple
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = ("Fit the whole-push topple head of a trained checkpoint on its frozen shape features "
                          "and write a new inference checkpoint (a new model_id).")
    parser.add_argument("--checkpoint", required=True, help="trained checkpoint (its dynamics stay unchanged)")
    parser.add_argument("--data", required=True, action="append",
                        help="dataset directory (its train and val splits); repeat to fit on several datasets")
    parser.add_argument("--out", required=True, help="the new checkpoint file")
    parser.add_argument("--max-train", type=int, default=24000, help="training simulations used (default 24000)")
    parser.add_argument("--partial", type=float, default=1.0 / 3.0,
                        help="fraction seen as one depth camera's partial view (default 1/3)")
    parser.add_argument("--epochs", type=int, default=60, help="epochs per ensemble member (default 60)")
    parser.add_argument("--members", type=int, default=5, help="ensemble members (default 5)")
    parser.add_argument("--family-folds", type=int, default=3,
                        help="leave-families-out folds whose predictions calibrate the head for new families "
                             "(default 3; 0: no calibration)")
    parser.add_argument("--feature-dropout", type=float, default=0.5,
                        help="chance that a training push's learned shape feature is hidden from the head, which "
                             "then decides from the physical descriptors alone (default 0.5; 0: never)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")


def _compact(result: dict[str, Any]) -> dict[str, Any]:
    """Scores without their reliability tables (for the checkpoint's config)."""
    return {k: (_compact(v) if isinstance(v, dict) else v) for k, v in result.items() if k != "reliability"}


def run(args: argparse.Namespace) -> int:
    from .checkpoint import load_checkpoint, save_checkpoint
    from .model import ModelConfig
    from .windows import load_sims

    if args.threads > 0:
        torch.set_num_threads(args.threads)
    if args.max_train < 100 or args.epochs < 1 or args.members < 1 or not 0.0 <= args.partial <= 1.0 \
            or not 0.0 <= args.feature_dropout < 1.0:
        raise ValueError("--max-train must be >= 100, --epochs and --members >= 1, --partial in [0, 1], "
                         "--feature-dropout in [0, 1)")
    ckpt = load_checkpoint(args.checkpoint)
    config = copy.deepcopy(ckpt["config"])
    # a stored topple_inputs (a removed option: sections.RETIRED) names the inputs of the head being replaced
    config["model"] = {**{k: v for k, v in config["model"].items() if k != "topple_inputs"}, "topple_head": True,
                       "topple_members": int(args.members)}
    model = DynamicsModel(ModelConfig.from_dict(config["model"]))
    state = {k: v for k, v in ckpt["model"].items() if not k.startswith("topple.")}  # refit an existing head
    missing = [k for k in model.load_state_dict(state, strict=False).missing_keys if not k.startswith("topple.")]
    if missing:
        raise ValueError(f"{args.checkpoint}: weights do not fit the model config (missing {missing[:3]})")
    folds = int(getattr(args, "family_folds", 0))
    if folds == 1 or folds < 0:
        raise ValueError(f"--family-folds must be 0 (no calibration) or at least 2, got {folds}")
    datas = [args.data] if isinstance(args.data, str) else list(args.data)
    train = [load_sims(d, ["train"]) for d in datas]
    val = [load_sims(d, ["val"]) for d in datas]
    result = fit_topple_head(model, train, val, max_train=args.max_train, partial=args.partial,
                             epochs=args.epochs, seed=args.seed, family_folds=folds,
                             feature_dropout=args.feature_dropout)
    resolved = [str(Path(d).resolve()) for d in datas]
    config["topple_fit"] = {"source": ckpt["model_id"], "data": resolved[0] if len(resolved) == 1 else resolved,
                            "max_train": args.max_train, "partial": args.partial, "epochs": args.epochs,
                            "members": args.members, "seed": args.seed, "family_folds": folds,
                            "feature_dropout": args.feature_dropout,
                            "validation": _compact(result)}
    model_id = save_checkpoint(args.out, model=model.eval(), config=config, dataset=ckpt.get("dataset", {}),
                               progress=ckpt.get("progress"), include_rng=False)
    print(f"wrote {args.out} (model_id {model_id}; dynamics of {ckpt['model_id']})")
    return 0
