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
"""`physdyn train`: train the dynamics model on a dataset (CPU or CUDA, single process or DDP via torchrun).

    physdyn train --config config/model_default.yaml --data DATA --out runs/default [--resume] \
        [--max-epochs N] [--time-limit 2h] [--set train.batch_size=256 ...]
    torchrun --nproc_per_node 2 -m physdyn_ros.cli train ...      (DDP; gloo on CPU, nccl on CUDA)

The run folder holds config.yaml (resolved), train_log.jsonl (one JSON line per epoch), checkpoint_last.pt
(full state, rewritten every epoch, every train.checkpoint_every_s seconds and on a time limit / SIGTERM /
Ctrl-C), checkpoint_best.pt (full state at the best validation metric) and model_best.pt (the same weights
without optimizer state: what ships as physdyn_ros/models/default.pt).

Reproducibility: the model is initialised from train.seed; epoch e visits the training simulations in the
order of a DistributedSampler seeded with (seed, e), and batch b draws its window starts and point subsets
from a generator seeded with (seed, e, b, rank). No data randomness is carried in state, so a run resumed
from checkpoint_last.pt (saved at a batch boundary) continues exactly as if it had never stopped.
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch

from .checkpoint import CheckpointError, load_checkpoint
from .config import apply_overrides, load_config, resolve_config, resolved_sections
from .distributed import barrier, init_distributed, process_device
from .loop import Run, StopFlag
from .model import ModelConfig


def train(cfg: dict[str, Any], data: str | Path, out: str | Path, resume: Optional[str] = None,
          time_limit: Optional[float] = None, device: str = "cpu", progress: bool = True,
          allow_data_change: bool = False, init: Optional[str] = None) -> dict[str, Any]:
    """Train (or resume) and return a summary. `cfg` is a resolved config (resolve_config).

    `init`: fine-tune, i.e. start a new run from this checkpoint's weights and normalisation statistics (its
    model section must equal cfg's); the optimiser, schedule and epochs start afresh.

    The steps: the device and process group, the checkpoints to start from, the data, the run's state (Run:
    model, optimiser, schedule, progress), then epochs until done, a time limit or a signal."""
    t_start = time.monotonic()
    d = init_distributed(device)
    dev = process_device(device, d)
    out = Path(out)
    tcfg = cfg["train"]
    if tcfg["threads"]:
        torch.set_num_threads(int(tcfg["threads"]))
    ckpt, base = _start_checkpoints(cfg, resume, init)
    train_sims, val_sims, identity = _load_data(cfg, data, ckpt, resume, allow_data_change)
    run = Run(cfg, d, dev, out, ckpt, base, train_sims, val_sims, identity)
    run.start_folder()

    run.last_save = time.monotonic()
    stopped = None
    with StopFlag() as stop:
        while run.prog["epoch"] < tcfg["epochs"] and stopped is None:
            epoch = run.prog["epoch"]
            stopped, sums, seen, t_epoch = run.train_epoch(stop, time_limit, t_start, progress)
            if stopped is not None:
                run.save(out / "checkpoint_last.pt")
                break
            run.end_epoch(epoch, sums, seen, t_epoch, progress)
            barrier(d)
    prog = run.prog
    summary = {"epochs_done": prog["epoch"], "step": prog["step"], "best_metric": prog["best_metric"],
               "best_epoch": prog["best_epoch"], "stopped": stopped, "out": str(out),
               "seconds": round(time.monotonic() - t_start, 1)}
    if d.enabled:
        import torch.distributed as dist

        barrier(d)
        dist.destroy_process_group()
    return summary


def _same_weights(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Two model configs whose weights are interchangeable: equal but for the physics prior (no weights of its
    own), which a fine-tune may swap between its two kinds or give another friction (a = the checkpoint's, b = the
    run's), and the whole-push topple head (not trained here). Keys a checkpoint written
    before they existed lacks count as their defaults."""
    a, b = asdict(ModelConfig.from_dict(dict(a))), asdict(ModelConfig.from_dict(dict(b)))
    # the head is fitted afterwards on frozen features
    drop = {"topple_head", "topple_hidden", "topple_members"}
    if {a["prior"], b["prior"]} <= {"sliding", "coupled"}:
        drop |= {"prior", "prior_friction"}
    return {k: v for k, v in a.items() if k not in drop} == {k: v for k, v in b.items() if k not in drop}


def _start_checkpoints(cfg: dict[str, Any], resume: Optional[str],
                       init: Optional[str]) -> tuple[Optional[dict[str, Any]], Optional[dict[str, Any]]]:
    """The checkpoint to resume (`resume`: its model, loss and data sections must equal cfg's) and the one to
    fine-tune from (`init`: its model section must equal cfg's); CheckpointError / ValueError otherwise."""
    ckpt: Optional[dict[str, Any]] = None
    if resume is not None:
        ckpt = load_checkpoint(resume, map_location="cpu")
        stored = resolved_sections(ckpt["config"])
        for section in ("model", "loss", "data"):
            if stored[section] != cfg[section]:
                raise CheckpointError(f"{resume}: its {section} config differs from the requested one; resume "
                                      "with the checkpoint's config (omit --config) or start a new run")

    base: Optional[dict[str, Any]] = None
    if init is not None:
        if resume is not None:
            raise ValueError("--init starts a new run from a checkpoint's weights; it cannot be combined with --resume")
        base = load_checkpoint(init, map_location="cpu")
        if not _same_weights(base["config"].get("model") or {}, cfg["model"]):
            raise CheckpointError(f"--init {init}: its model config differs from the requested one (only the "
                                  "prior's kind, sliding or coupled, and its friction may change in a fine-tune)")
    return ckpt, base


def _load_data(cfg: dict[str, Any], data: str | Path, ckpt: Optional[dict[str, Any]], resume: Optional[str],
               allow_data_change: bool) -> tuple[Any, Any, dict[str, Any]]:
    """The training and validation simulations (cfg's data section) and the dataset's identity; a resumed run
    must continue on the dataset it started on unless allow_data_change."""
    from .windows import dataset_identity, load_sims

    dcfg = cfg["data"]
    train_sims = load_sims(data, ["train"], dcfg["categories"], dcfg["exclude_categories"])
    if dcfg["max_train_sims"]:
        train_sims = train_sims.subset(np.arange(min(int(dcfg["max_train_sims"]), len(train_sims))))
    val_sims = load_sims(data, ["val"], dcfg["categories"], dcfg["exclude_categories"])
    identity = dataset_identity(data, train_sims.manifest)
    if ckpt is not None:
        old = ckpt.get("dataset", {}).get("manifest_sha256")
        if old != identity["manifest_sha256"] and not allow_data_change:
            raise CheckpointError(f"{resume} was trained on a different dataset (manifest sha256 {str(old)[:12]} "
                                  f"vs {identity['manifest_sha256'][:12]}); pass --allow-data-change to continue")
    return train_sims, val_sims, identity


def parse_duration(text: Optional[str]) -> Optional[float]:
    """'90', '90s', '30m', '2h' -> seconds."""
    if text is None:
        return None
    text = str(text).strip().lower()
    mult = {"s": 1, "m": 60, "h": 3600}.get(text[-1:], None)
    try:
        value = float(text[:-1]) * mult if mult else float(text)
    except ValueError:
        raise ValueError(f"--time-limit expects seconds or a number with s/m/h, got {text!r}") from None
    if value <= 0:
        raise ValueError("--time-limit must be positive")
    return value


# ----------------------------------------------------------------------------------------------------- CLI
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default=None,
                        help="config YAML (model/loss/train/data sections), e.g. config/model_default.yaml; "
                             "optional with --resume (the checkpoint's config is used)")
    parser.add_argument("--data", required=True, help="dataset directory (physdyn generate)")
    parser.add_argument("--out", required=True, help="run folder for checkpoints and logs")
    parser.add_argument("--resume", nargs="?", const="auto", default=None,
                        help="resume from a checkpoint; without a path: OUT/checkpoint_last.pt if it exists, "
                             "else start fresh (safe to use in restart loops)")
    parser.add_argument("--init", default=None, metavar="CHECKPOINT",
                        help="fine-tune: start a new run from this checkpoint's weights and normalisation (its "
                             "config is used unless --config is given; change train values with --set)")
    parser.add_argument("--max-epochs", type=int, default=None,
                        help="train until this many epochs (overrides train.epochs)")
    parser.add_argument("--time-limit", default=None, help="stop cleanly after this long (e.g. 3600, 90m, 2h)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (overrides train.threads)")
    parser.add_argument("--seed", type=int, default=None, help="overrides train.seed")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override one config value, e.g. --set train.batch_size=256 (repeatable)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar; one summary line per epoch")
    parser.add_argument("--allow-data-change", action="store_true",
                        help="resume even if the dataset differs from the checkpoint's")


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    resume: Optional[str] = None
    if args.resume == "auto":
        resume = str(out / "checkpoint_last.pt") if (out / "checkpoint_last.pt").is_file() else None
    elif args.resume is not None:
        resume = args.resume
        if not Path(resume).is_file():
            raise FileNotFoundError(f"--resume checkpoint {resume} does not exist")
    elif (out / "checkpoint_last.pt").exists():
        raise FileExistsError(f"{out} already holds a run (checkpoint_last.pt); pass --resume to continue it "
                              "or choose another --out")
    if resume is not None:
        base = copy.deepcopy(load_checkpoint(resume)["config"])
        if args.config:
            requested = load_config(args.config, args.set)
            stored = resolved_sections(base)
            for section in ("model", "loss", "data"):
                if requested[section] != stored[section]:
                    raise CheckpointError(f"--config {args.config}: its {section} section differs from the "
                                          f"checkpoint's; resume without --config or start a new --out")
            base["train"] = requested["train"]
        else:
            apply_overrides(base, args.set)
        cfg = resolve_config(base)
    elif args.config:
        cfg = load_config(args.config, args.set)
    elif args.init:
        if not Path(args.init).is_file():
            raise FileNotFoundError(f"--init checkpoint {args.init} does not exist")
        base = copy.deepcopy(load_checkpoint(args.init)["config"])
        # a fine-tune changes the shape features the topple head reads: it is not carried over (refit it with
        # physdyn fit-topple on the result), nor the record of its fit
        base.pop("topple_fit", None)
        base["model"] = {**base["model"], "topple_head": False}
        apply_overrides(base, args.set)
        cfg = resolve_config(base)
    else:
        raise ValueError("--config (or --init) is required for a new run")
    if args.max_epochs is not None:
        cfg["train"]["epochs"] = int(args.max_epochs)
    if args.threads is not None:
        cfg["train"]["threads"] = int(args.threads)
    if args.seed is not None:
        if resume is not None and args.seed != cfg["train"]["seed"]:
            raise ValueError("--seed cannot change on resume")
        cfg["train"]["seed"] = int(args.seed)
    summary = train(cfg, args.data, out, resume, parse_duration(args.time_limit), args.device,
                    progress=not args.no_progress and sys.stderr.isatty(), allow_data_change=args.allow_data_change,
                    init=args.init)
    if int(os.environ.get("RANK", "0")) == 0:
        print(json.dumps(summary))
    return 0
