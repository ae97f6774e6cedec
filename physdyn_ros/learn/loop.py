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
"""The training loop: one run's state (model, optimiser, schedule, progress, data), its epochs and steps, the
loss of a batch and the validation after an epoch. learn/train.py sets a run up and drives it.
"""
from __future__ import annotations

import json
import math
import signal
import sys
import time
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch
import yaml

from .checkpoint import CheckpointError, restore_rng, save_checkpoint
from .distributed import Dist, all_true
from .losses import LossConfig, dynamics_loss
from .model import DynamicsModel, ModelConfig, count_parameters


class StopFlag:
    """SIGTERM / first Ctrl-C ask for a clean stop at the next batch boundary (a second Ctrl-C aborts)."""

    def __init__(self) -> None:
        self.requested = False
        self._old: dict[int, Any] = {}

    def __enter__(self) -> "StopFlag":
        if threading_main():  # signal handlers can only be set from the main thread
            for sig in (signal.SIGTERM, signal.SIGINT):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.requested = True

    def __exit__(self, *exc: Any) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


def threading_main() -> bool:
    """True in the main thread (the only one that may set signal handlers)."""
    import threading

    return threading.current_thread() is threading.main_thread()


def _to(batch: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    return {k: v.to(device, non_blocking=True) for k, v in batch.items()}


def batch_loss(model: torch.nn.Module, core: DynamicsModel, batch: dict[str, torch.Tensor], loss_cfg: LossConfig,
               feedback: bool) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The loss of one batch of windows (teacher-forced, or closed-loop with `feedback`) and its parts; `model`
    is `core` or its DDP wrapper. The centre-of-mass head's error joins the total when the model has one."""
    raw, com = core.split_com(model(batch["cloud"], batch["vel"], batch["angvel"], feedback))
    target = core.normalize_targets(batch["d_vel"], batch["d_angvel"], batch["d_pos"], batch["d_rot"])
    total, parts = dynamics_loss(raw, target, batch["topple"], loss_cfg)
    if com is not None:  # the centre-of-mass head: L2 error in cloud-scale units
        com_loss = torch.linalg.vector_norm(com - batch["com"] / core.normalization()["cloud"], dim=-1).mean()
        total = total + loss_cfg.w_com * com_loss
        parts["com"] = com_loss.detach()
        parts["total"] = total.detach()
    return total, parts


@torch.no_grad()
def validate(core: DynamicsModel, val_ds: Any, val_index: np.ndarray, val_starts: np.ndarray, cfg: dict[str, Any],
             loss_cfg: LossConfig, device: torch.device) -> dict[str, float]:
    """Loss on the fixed validation windows, teacher-forced (val_*) and closed-loop (val_closed_*), and the
    median final pose error of whole roll-outs of the validation sequences that do not topple."""
    from .windows import make_windows

    core.eval()
    sums: dict[str, float] = {}
    count = 0
    for i in range(0, len(val_index), 512):
        batch = _to(make_windows(val_ds, val_index[i:i + 512], val_starts[i:i + 512], cfg["train"]["window"],
                                 core.cfg.num_points, None), device)
        n = len(val_index[i:i + 512])
        for mode, feedback in (("", False), ("closed_", True)):  # teacher-forced and closed-loop windows
            _, parts = batch_loss(core, core, batch, loss_cfg, feedback)
            for k, v in parts.items():
                sums[f"val_{mode}{k}"] = sums.get(f"val_{mode}{k}", 0.0) + float(v) * n
        count += n
    out = {k: v / max(count, 1) for k, v in sums.items()}
    out["val_loss"] = out.pop("val_total")
    out["val_closed_loss"] = out.pop("val_closed_total")
    horizon = min(int(cfg["train"]["val_rollout_horizon"]), val_ds.num_frames - 1)
    if horizon > 0:
        from .evaluate import ground_truth, model_rollouts, pose_errors

        keep = np.flatnonzero(val_ds.topple_index < 0)
        if keep.size:
            pred = model_rollouts(core, val_ds, keep, horizon, 1, 256, device)
            err = pose_errors(pred, ground_truth(val_ds, keep, horizon))
            out["val_final_pos_cm"] = float(np.median(err["pos"][:, -1]))
            out["val_final_rot_deg"] = float(np.median(err["rot"][:, -1]))
    return out


def lr_factor(step: int, cfg: dict[str, Any]) -> float:
    """Multiplier of the base lr after `step` optimizer steps (sequences = step * batch_size)."""
    seen = step * cfg["batch_size"] / max(cfg["lr_decay_every"], 1)
    exponent = math.floor(seen) if cfg["lr_staircase"] else seen
    return max(cfg["lr_decay"] ** exponent, cfg["lr_min"] / cfg["lr"])


class Run:
    """One training run's state: the model (DDP-wrapped when distributed), optimiser, schedule, progress
    (epoch, batch, step, best metric), the training windows and their sampler, the fixed validation windows."""

    def __init__(self, cfg: dict[str, Any], d: Dist, dev: torch.device, out: Path, ckpt: Optional[dict[str, Any]],
                 base: Optional[dict[str, Any]], train_sims: Any, val_sims: Any, identity: dict[str, Any]) -> None:
        from torch.utils.data.distributed import DistributedSampler

        from .windows import WindowDataset, compute_stats, fixed_windows

        self.cfg, self.d, self.dev, self.out, self.identity = cfg, d, dev, out, identity
        self.train_sims, self.val_sims = train_sims, val_sims
        tcfg, dcfg = cfg["train"], cfg["data"]
        self.tcfg = tcfg
        # Fine-tuning keeps the pretrained statistics: the network's weights are tied to them.
        start = ckpt or base
        stats = dict(start["normalization"]) if start is not None else compute_stats(train_sims)

        torch.manual_seed(tcfg["seed"])
        model_cfg = ModelConfig.from_dict(cfg["model"])
        self.core = DynamicsModel(model_cfg, stats).to(dev)
        self.loss_cfg = LossConfig.from_dict(cfg["loss"])
        self.optimizer = torch.optim.Adam(self.core.parameters(), lr=tcfg["lr"], weight_decay=tcfg["weight_decay"])
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(self.optimizer, lambda step: lr_factor(step, tcfg))
        self.prog: dict[str, Any] = {"epoch": 0, "batch": 0, "step": 0, "best_metric": None, "best_epoch": None}
        if base is not None:  # the dynamics weights; a topple head is refit on the new features (fit-topple)
            state = {k: v for k, v in base["model"].items() if not k.startswith("topple.")}
            res = self.core.load_state_dict(state, strict=False)
            bad = [k for k in res.missing_keys if not k.startswith("topple.")] + list(res.unexpected_keys)
            if bad:
                raise CheckpointError(f"the --init checkpoint's weights do not fit the model: {bad[:3]}")
        if ckpt is not None:
            self.core.load_state_dict(ckpt["model"])
            self.optimizer.load_state_dict(ckpt["optimizer"])
            self.scheduler.load_state_dict(ckpt["scheduler"])
            if ckpt.get("rng"):
                restore_rng(ckpt["rng"])
            self.prog.update(ckpt.get("progress", {}))
        self.model: torch.nn.Module = self.core
        if d.enabled:
            self.model = torch.nn.parallel.DistributedDataParallel(
                self.core, device_ids=[dev.index] if dev.type == "cuda" else None)

        self.ds = WindowDataset(train_sims, tcfg["window"], model_cfg.num_points,
                                partial=dcfg.get("partial_views", 0.0), noise=dcfg.get("view_noise", 0.0))
        self.sampler: DistributedSampler = DistributedSampler(self.ds, num_replicas=d.world, rank=d.rank,
                                                              shuffle=True, seed=tcfg["seed"])
        if tcfg["batch_size"] % d.world:
            raise ValueError(f"train.batch_size {tcfg['batch_size']} must be divisible by the {d.world} processes")
        self.per_rank = tcfg["batch_size"] // d.world
        self.val_index, self.val_starts = fixed_windows(val_sims, tcfg["window"], tcfg["val_windows_per_sim"],
                                                        tcfg["val_seed"])
        self.last_save = time.monotonic()

    def start_folder(self) -> None:
        """The main process creates the run folder, writes the resolved config.yaml and says what it trains."""
        if self.d.main:
            tcfg = self.tcfg
            self.out.mkdir(parents=True, exist_ok=True)
            (self.out / "config.yaml").write_text(yaml.safe_dump(self.cfg, sort_keys=False))
            print(f"train: {len(self.train_sims)} train / {len(self.val_sims)} val simulations, {self.d.world} "
                  f"process(es) on {self.dev}, {count_parameters(self.core)['total']:,} parameters, batch "
                  f"{tcfg['batch_size']}", file=sys.stderr)

    def save(self, path: Path, with_optimizer: bool = True) -> None:
        """A checkpoint (main process only): the full state, or the weights alone (with_optimizer False)."""
        if self.d.main:
            save_checkpoint(path, model=self.core, config=self.cfg, dataset=self.identity,
                            optimizer=self.optimizer if with_optimizer else None,
                            scheduler=self.scheduler if with_optimizer else None, progress=self.prog,
                            include_rng=with_optimizer)

    def train_epoch(self, stop: StopFlag, time_limit: Optional[float], t_start: float,
                    progress: bool) -> tuple[Optional[str], dict[str, float], int, float]:
        """The batches of epoch prog["epoch"] from prog["batch"] on. Returns why it stopped early ("time limit",
        "signal") or None, the sums of the loss parts, the number of batches run and the epoch's start time."""
        tcfg, d, prog = self.tcfg, self.d, self.prog
        epoch = prog["epoch"]
        self.sampler.set_epoch(epoch)
        order = np.fromiter(iter(self.sampler), dtype=np.int64)
        n_batches = math.ceil(len(order) / self.per_rank)
        bar = None
        if progress and d.main:
            from tqdm import tqdm

            bar = tqdm(total=n_batches, initial=prog["batch"], desc=f"epoch {epoch + 1}/{tcfg['epochs']}",
                       dynamic_ncols=True, leave=False, file=sys.stderr)
        self.core.train()
        running: dict[str, float] = {}
        sums: dict[str, float] = {}
        seen = 0
        stopped = None
        t_epoch = time.monotonic()
        for b in range(prog["batch"], n_batches):
            parts = self._step(order, epoch, b)
            for k, v in parts.items():
                x = float(v)
                running[k] = x if k not in running else 0.95 * running[k] + 0.05 * x
                sums[k] = sums.get(k, 0.0) + x
            seen += 1
            if bar is not None:
                bar.update(1)
                bar.set_postfix({k: f"{running[k]:.3f}" for k in ("total", "vel", "pos", "rot", "topple")})
            over_time = time_limit is not None and time.monotonic() - t_start > time_limit
            if all_true(stop.requested or over_time, d, self.dev):
                stopped = "time limit" if over_time else "signal"
                break
            if time.monotonic() - self.last_save > tcfg["checkpoint_every_s"] and b + 1 < n_batches:
                self.save(self.out / "checkpoint_last.pt")
                self.last_save = time.monotonic()
        if bar is not None:
            bar.close()
        return stopped, sums, seen, t_epoch

    def _step(self, order: np.ndarray, epoch: int, b: int) -> dict[str, torch.Tensor]:
        """One optimiser step on batch b of the epoch; its window starts and points come from (seed, epoch, b,
        rank), teacher forcing or closed loop from (seed, epoch, b). Returns the loss parts."""
        tcfg = self.tcfg
        rng = np.random.default_rng([tcfg["seed"], epoch, b, self.d.rank])
        mode_rng = np.random.default_rng([tcfg["seed"], epoch, b])  # same on all ranks
        feedback = bool(mode_rng.random() < tcfg["rollout_fraction"])
        batch = _to(self.ds.batch(order[b * self.per_rank:(b + 1) * self.per_rank], rng), self.dev)
        loss, parts = batch_loss(self.model, self.core, batch, self.loss_cfg, feedback)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if tcfg["grad_clip"]:
            torch.nn.utils.clip_grad_norm_(self.core.parameters(), tcfg["grad_clip"])
        self.optimizer.step()
        self.scheduler.step()
        self.prog["step"] += 1
        self.prog["batch"] = b + 1
        return parts

    def end_epoch(self, epoch: int, sums: dict[str, float], seen: int, t_epoch: float, progress: bool) -> None:
        """After a whole epoch: validation (every val_every epochs and at the end), the best and last
        checkpoints, one train_log.jsonl line (printed too without a progress bar)."""
        tcfg, d, prog, out = self.tcfg, self.d, self.prog, self.out
        prog["epoch"], prog["batch"] = epoch + 1, 0
        record: dict[str, Any] = {"epoch": epoch + 1, "step": prog["step"],
                                  "lr": self.optimizer.param_groups[0]["lr"],
                                  "epoch_s": round(time.monotonic() - t_epoch, 2)}
        record.update({f"train_{k}": v / max(seen, 1) for k, v in sums.items()})
        improved = False
        if d.main and ((epoch + 1) % tcfg["val_every"] == 0 or epoch + 1 == tcfg["epochs"]):
            record.update(validate(self.core, self.val_sims, self.val_index, self.val_starts, self.cfg,
                                   self.loss_cfg, self.dev))
            metric = record.get(tcfg["select_metric"], record["val_loss"])
            if prog["best_metric"] is None or metric < prog["best_metric"]:
                prog["best_metric"], prog["best_epoch"], improved = float(metric), epoch + 1, True
            record["best"] = improved
        if d.main:
            if improved:
                self.save(out / "checkpoint_best.pt")
                self.save(out / "model_best.pt", with_optimizer=False)
            self.save(out / "checkpoint_last.pt")
            self.last_save = time.monotonic()
            with open(out / "train_log.jsonl", "a") as fh:
                fh.write(json.dumps(record) + "\n")
            if not progress:
                keys = ("epoch", "train_total", "val_loss", "val_closed_loss", "val_final_pos_cm",
                        "val_final_rot_deg", "lr", "epoch_s")
                print(" ".join(f"{k}={record[k]:.4g}" if isinstance(record.get(k), float)
                               else f"{k}={record.get(k)}" for k in keys if k in record), file=sys.stderr)
