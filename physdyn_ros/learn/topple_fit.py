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
from typing import Any, Callable, Optional

import numpy as np
import torch

from .evaluate import _fmt, calibration, topple_scores
from .model import DynamicsModel
from .support import push_quantities, support_descriptors
from .topple import ToppleHead
from .windows import SimArrays, sequences


@torch.inference_mode()
def topple_inputs(model: DynamicsModel, sims: SimArrays, index: np.ndarray, partial: float = 0.0,
                  noise: float = 0.002, view_seed: int = 0, batch_size: int = 256) -> dict[str, np.ndarray]:
    """feature (B, F), desc (B, D), push (B, E), label (B,) of simulations `index` (frame 0, C frame)."""
    parts: dict[str, list[np.ndarray]] = {"feature": [], "desc": [], "push": [], "label": []}
    for start in range(0, len(index), batch_size):
        idx = index[start:start + batch_size]
        seq = sequences(sims, 1, model.cfg.num_points, idx, partial, noise, view_seed=view_seed + start)
        feature = model.encode(seq["cloud"])
        desc = support_descriptors(seq["cloud"].numpy(), model.com_estimate(feature).numpy())
        parts["feature"].append(feature.numpy())
        parts["desc"].append(desc)
        parts["push"].append(push_quantities(desc, seq["vel"][:, 0].numpy(), seq["angvel"][:, 0].numpy()))
        parts["label"].append((sims.topple_index[idx] >= 0).astype(np.float32))
    return {k: np.concatenate(v) for k, v in parts.items()}


def _join(*sets: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: np.concatenate([s[k] for s in sets]) for k in sets[0]}


def scores(prob: np.ndarray, label: np.ndarray, threshold: float = 0.5) -> dict[str, Any]:
    """physdyn evaluate's topple scores at `threshold` (F1, precision, recall; None where undefined) with the
    Brier score and reliability table."""
    true = label > 0.5
    return {**topple_scores(prob > threshold, true), **calibration(prob, true)}


def fit_topple_head(model: DynamicsModel, train: SimArrays, val: SimArrays, *, max_train: int = 24000,
                    partial: float = 1.0 / 3.0, noise: float = 0.002, epochs: int = 120, batch_size: int = 512,
                    lr: float = 3e-3, weight_decay: float = 1e-3, seed: int = 0,
                    log: Optional[Callable[[str], None]] = print) -> dict[str, Any]:
    """Fit model.topple (a ToppleHead) in place; returns validation scores. The rest of the model is frozen."""
    head = model.topple
    if not isinstance(head, ToppleHead):
        raise ValueError("the model has no topple head (model.topple_head: true)")
    t0 = time.time()
    rng = np.random.default_rng(seed)
    n = min(max_train, len(train))
    index = np.sort(rng.choice(len(train), n, replace=False))
    n_part = int(round(partial * n))
    parted = rng.permutation(n)[:n_part]
    full_rows = np.setdiff1d(np.arange(n), parted)
    model.eval()
    data = _join(topple_inputs(model, train, index[full_rows], 0.0, noise, seed),
                 topple_inputs(model, train, np.sort(index[parted]), 1.0, noise, seed + 1))
    vidx = np.arange(len(val))
    vdata = _join(topple_inputs(model, val, vidx, 0.0, noise, seed + 2),
                  topple_inputs(model, val, vidx, 1.0, noise, seed + 3))
    if log:
        log(f"topple head: {len(data['label'])} training pushes ({data['label'].mean():.1%} toppled), "
            f"{len(vdata['label'])} validation, inputs in {time.time() - t0:.0f} s")

    def raw(d: dict[str, np.ndarray]) -> torch.Tensor:
        with torch.no_grad():
            return head.raw_inputs(torch.from_numpy(d["feature"]).float(), torch.from_numpy(d["desc"]).float(),
                                   torch.from_numpy(d["push"]).float())

    x, y = raw(data), torch.from_numpy(data["label"])
    xv, yv = raw(vdata), torch.from_numpy(vdata["label"])
    head.mean.copy_(x.mean(0))
    head.std.copy_(x.std(0).clamp_min(1e-6))
    head.set_novelty(x)
    loss_fn = torch.nn.functional.binary_cross_entropy_with_logits
    for k, member in enumerate(head.members):
        gen = torch.Generator().manual_seed(seed * 1000 + k)
        for layer in member.modules():
            if isinstance(layer, torch.nn.Linear):
                torch.nn.init.kaiming_uniform_(layer.weight, a=5 ** 0.5, generator=gen)
                torch.nn.init.zeros_(layer.bias)
        opt = torch.optim.Adam(member.parameters(), lr=lr, weight_decay=weight_decay)
        zx, zv = (x - head.mean) / head.std, (xv - head.mean) / head.std
        best, best_state = float("inf"), None
        for _ in range(epochs):
            member.train()
            perm = torch.randperm(len(zx), generator=gen)
            for i in range(0, len(zx), batch_size):
                b = perm[i:i + batch_size]
                loss = loss_fn(member(zx[b])[:, 0], y[b])
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
    with torch.no_grad():
        prob = torch.sigmoid(head.member_logits(xv)).mean(0).numpy()
    result = scores(prob, vdata["label"])
    result["seconds"] = round(time.time() - t0, 1)
    result["train_pushes"] = int(len(y))
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
    parser.add_argument("--data", required=True, help="dataset directory (its train and val splits)")
    parser.add_argument("--out", required=True, help="the new checkpoint file")
    parser.add_argument("--max-train", type=int, default=24000, help="training simulations used (default 24000)")
    parser.add_argument("--partial", type=float, default=1.0 / 3.0,
                        help="fraction seen as one depth camera's partial view (default 1/3)")
    parser.add_argument("--epochs", type=int, default=60, help="epochs per ensemble member (default 60)")
    parser.add_argument("--members", type=int, default=5, help="ensemble members (default 5)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")


def run(args: argparse.Namespace) -> int:
    from .checkpoint import load_checkpoint, save_checkpoint
    from .model import ModelConfig
    from .windows import load_sims

    if args.threads > 0:
        torch.set_num_threads(args.threads)
    if args.max_train < 100 or args.epochs < 1 or args.members < 1 or not 0.0 <= args.partial <= 1.0:
        raise ValueError("--max-train must be >= 100, --epochs and --members >= 1, --partial in [0, 1]")
    ckpt = load_checkpoint(args.checkpoint)
    config = copy.deepcopy(ckpt["config"])
    config["model"] = dict(config["model"], topple_head=True, topple_members=int(args.members))
    model = DynamicsModel(ModelConfig.from_dict(config["model"]))
    state = {k: v for k, v in ckpt["model"].items() if not k.startswith("topple.")}  # refit an existing head
    missing = [k for k in model.load_state_dict(state, strict=False).missing_keys if not k.startswith("topple.")]
    if missing:
        raise ValueError(f"{args.checkpoint}: weights do not fit the model config (missing {missing[:3]})")
    train, val = load_sims(args.data, ["train"]), load_sims(args.data, ["val"])
    result = fit_topple_head(model, train, val, max_train=args.max_train, partial=args.partial,
                             epochs=args.epochs, seed=args.seed)
    config["topple_fit"] = {"source": ckpt["model_id"], "data": str(Path(args.data).resolve()),
                            "max_train": args.max_train, "partial": args.partial, "epochs": args.epochs,
                            "members": args.members, "seed": args.seed,
                            "validation": {k: v for k, v in result.items() if k != "reliability"}}
    model_id = save_checkpoint(args.out, model=model.eval(), config=config, dataset=ckpt.get("dataset", {}),
                               progress=ckpt.get("progress"), include_rng=False)
    print(f"wrote {args.out} (model_id {model_id}; dynamics of {ckpt['model_id']})")
    return 0
