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
import math
import os
import re
import signal
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch
import yaml

from .checkpoint import CheckpointError, load_checkpoint, restore_rng, save_checkpoint
from .losses import LossConfig, dynamics_loss
from .sections import known_keys
from .model import DynamicsModel, ModelConfig, count_parameters


SELECT_METRICS = ("val_loss", "val_closed_loss", "val_final_pos_cm")


@dataclass
class TrainConfig:
    """Optimisation (the `train:` section of a config YAML)."""

    seed: int = 0
    epochs: int = 200  # one epoch = one random window per training simulation (the paper's epoch)
    batch_size: int = 128  # global batch; each of W DDP processes takes batch_size / W
    window: int = 15  # frames per training window (14 predicted steps)
    lr: float = 1e-3
    lr_decay: float = 0.75  # lr *= lr_decay every lr_decay_every sequences ...
    lr_decay_every: int = 300_000  # ... (paper: 0.75 per 300k sequences, staircase, floored at lr_min)
    lr_staircase: bool = True
    lr_min: float = 1e-5
    weight_decay: float = 0.0
    grad_clip: Optional[float] = None  # max gradient norm; None = no clipping (paper)
    rollout_fraction: float = 0.0  # fraction of batches trained closed-loop (own velocities fed back); paper 0
    val_every: int = 1  # epochs between validations (paper: 100 epochs of its much larger data)
    val_windows_per_sim: int = 2  # fixed validation windows per validation simulation
    val_seed: int = 0  # seed of the fixed validation windows (independent of `seed`)
    val_rollout_horizon: int = 60  # also log roll-out errors on whole validation sequences (0 = off)
    select_metric: str = "val_loss"  # val_loss | val_closed_loss | val_final_pos_cm (median, whole sequences)
    threads: Optional[int] = None  # torch CPU threads (None: torch's default)
    checkpoint_every_s: float = 600.0

    def __post_init__(self) -> None:
        if self.select_metric not in SELECT_METRICS:
            raise ValueError(f"train.select_metric must be one of {SELECT_METRICS}, got {self.select_metric!r}")
        if self.batch_size < 1 or self.window < 2 or self.epochs < 0 or self.val_every < 1:
            raise ValueError("train: batch_size >= 1, window >= 2, epochs >= 0 and val_every >= 1 are required")
        if not 0.0 <= self.rollout_fraction <= 1.0:
            raise ValueError("train.rollout_fraction must be in [0, 1]")


@dataclass
class DataConfig:
    """Which simulations to train on (the `data:` section): leave-one-category-out is an exclusion here."""

    categories: Optional[list[str]] = None
    exclude_categories: Optional[list[str]] = None
    max_train_sims: Optional[int] = None  # use only the first N training simulations (debugging, overfit tests)
    # Clouds as a robot's depth camera sees them (learn/views.py): this fraction of the training windows sees
    # only the visible side from a random viewpoint, with view_noise m of Gaussian noise.
    partial_views: float = 0.0
    view_noise: float = 0.002

    def __post_init__(self) -> None:
        if not 0.0 <= float(self.partial_views) <= 1.0 or float(self.view_noise) < 0:
            raise ValueError(f"data.partial_views must be in [0, 1] and data.view_noise >= 0, got "
                             f"{self.partial_views}, {self.view_noise}")


def _section(cls: type, data: Optional[dict[str, Any]], name: str) -> Any:
    return cls(**known_keys(cls, data or {}, name))


def resolve_config(raw: dict[str, Any]) -> dict[str, Any]:
    """Validate a config dict (model / loss / train / data sections) and fill in defaults."""
    model = ModelConfig.from_dict(dict(raw.get("model") or {}))  # first: it names a removed option it needs
    unknown = sorted(set(raw) - {"model", "loss", "train", "data"})
    if unknown:
        raise ValueError(f"unknown config sections {unknown} (expected model, loss, train, data)")
    loss = LossConfig.from_dict(dict(raw.get("loss") or {}))
    train = _section(TrainConfig, raw.get("train"), "train")
    data = _section(DataConfig, raw.get("data"), "data")
    return {"model": model.to_dict(), "loss": loss.to_dict(), "train": asdict(train), "data": asdict(data)}


def _resolved_sections(config: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint's stored config with the defaults of keys added since it was written and without the
    removed ones (sections.RETIRED): comparable with a resolved config."""
    return resolve_config({k: config.get(k) for k in ("model", "loss", "train", "data")})


def load_config(path: str | Path, overrides: Optional[list[str]] = None) -> dict[str, Any]:
    """Read a YAML config and apply `section.key=value` overrides (values parsed as YAML)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file {path} does not exist")
    raw = yaml.safe_load(path.read_text()) or {}
    if not isinstance(raw, dict):
        raise ValueError(f"{path}: a config is a mapping of sections")
    apply_overrides(raw, overrides or [])
    return resolve_config(raw)


_EXPONENT = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)[eE][+-]?\d+")


def apply_overrides(raw: dict[str, Any], overrides: list[str]) -> None:
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or "." not in key:
            raise ValueError(f"--set expects section.key=value, got {item!r}")
        section, name = key.split(".", 1)
        raw.setdefault(section, {})
        if raw[section] is None:
            raw[section] = {}
        parsed = yaml.safe_load(value)
        if isinstance(parsed, str) and _EXPONENT.fullmatch(parsed.strip()):
            parsed = float(parsed)  # YAML 1.1 reads an exponent without a dot (lr=1e-4) as a string
        raw[section][name] = parsed


def lr_factor(step: int, cfg: dict[str, Any]) -> float:
    """Multiplier of the base lr after `step` optimizer steps (sequences = step * batch_size)."""
    seen = step * cfg["batch_size"] / max(cfg["lr_decay_every"], 1)
    exponent = math.floor(seen) if cfg["lr_staircase"] else seen
    return max(cfg["lr_decay"] ** exponent, cfg["lr_min"] / cfg["lr"])


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


# --------------------------------------------------------------------------------------------- distributed
@dataclass
class Dist:
    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @property
    def main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world > 1


def init_distributed(device: str) -> Dist:
    """Join the process group when launched by torchrun (WORLD_SIZE > 1)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Dist()
    import torch.distributed as dist

    backend = "nccl" if device.startswith("cuda") else "gloo"
    if not dist.is_initialized():
        dist.init_process_group(backend=backend)
    return Dist(rank=dist.get_rank(), world=dist.get_world_size(), local_rank=int(os.environ.get("LOCAL_RANK", "0")))


def _all_true(flag: bool, d: Dist, device: torch.device) -> bool:
    """OR of a stop flag over processes (all must stop at the same batch)."""
    if not d.enabled:
        return flag
    import torch.distributed as dist

    t = torch.tensor([1.0 if flag else 0.0], device=device)
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return bool(t.item() > 0)


def _barrier(d: Dist) -> None:
    if d.enabled:
        import torch.distributed as dist

        dist.barrier()


# ------------------------------------------------------------------------------------------------ training
class _StopFlag:
    """SIGTERM / first Ctrl-C ask for a clean stop at the next batch boundary (a second Ctrl-C aborts)."""

    def __init__(self) -> None:
        self.requested = False
        self._old: dict[int, Any] = {}

    def __enter__(self) -> "_StopFlag":
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
    import threading

    return threading.current_thread() is threading.main_thread()


def _to(batch: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    return {k: v.to(device, non_blocking=True) for k, v in batch.items()}


def batch_loss(model: torch.nn.Module, core: DynamicsModel, batch: dict[str, torch.Tensor], loss_cfg: LossConfig,
               feedback: bool) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
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


def train(cfg: dict[str, Any], data: str | Path, out: str | Path, resume: Optional[str] = None,
          time_limit: Optional[float] = None, device: str = "cpu", progress: bool = True,
          allow_data_change: bool = False, init: Optional[str] = None) -> dict[str, Any]:
    """Train (or resume) and return a summary. `cfg` is a resolved config (resolve_config).

    `init`: fine-tune, i.e. start a new run from this checkpoint's weights and normalisation statistics (its
    model section must equal cfg's); the optimiser, schedule and epochs start afresh.

    The steps: the device and process group, the checkpoints to start from, the data, the run's state (_Run:
    model, optimiser, schedule, progress), then epochs until done, a time limit or a signal."""
    t_start = time.monotonic()
    d = init_distributed(device)
    dev = _device(device, d)
    out = Path(out)
    tcfg = cfg["train"]
    if tcfg["threads"]:
        torch.set_num_threads(int(tcfg["threads"]))
    ckpt, base = _start_checkpoints(cfg, resume, init)
    train_sims, val_sims, identity = _load_data(cfg, data, ckpt, resume, allow_data_change)
    run = _Run(cfg, d, dev, out, ckpt, base, train_sims, val_sims, identity)
    run.start_folder()

    run.last_save = time.monotonic()
    stopped = None
    with _StopFlag() as stop:
        while run.prog["epoch"] < tcfg["epochs"] and stopped is None:
            epoch = run.prog["epoch"]
            stopped, sums, seen, t_epoch = run.train_epoch(stop, time_limit, t_start, progress)
            if stopped is not None:
                run.save(out / "checkpoint_last.pt")
                break
            run.end_epoch(epoch, sums, seen, t_epoch, progress)
            _barrier(d)
    prog = run.prog
    summary = {"epochs_done": prog["epoch"], "step": prog["step"], "best_metric": prog["best_metric"],
               "best_epoch": prog["best_epoch"], "stopped": stopped, "out": str(out),
               "seconds": round(time.monotonic() - t_start, 1)}
    if d.enabled:
        import torch.distributed as dist

        _barrier(d)
        dist.destroy_process_group()
    return summary


def _device(device: str, d: Dist) -> torch.device:
    """This process's torch device (under torchrun on CUDA: its local GPU)."""
    if device.startswith("cuda"):
        dev = torch.device("cuda", d.local_rank if d.enabled else (torch.device(device).index or 0))
        torch.cuda.set_device(dev)
        return dev
    return torch.device("cpu")


def _same_weights(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Two model configs whose weights are interchangeable: equal but for the physics prior (no weights of its
    own), which a fine-tune may swap between its two kinds or give another friction (a = the checkpoint's, b = the
    run's), and the whole-push topple head (not trained here). Keys a checkpoint written
    before they existed lacks count as their defaults."""
    from dataclasses import asdict

    from .model import ModelConfig

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
        stored = _resolved_sections(ckpt["config"])
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


class _Run:
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

    def train_epoch(self, stop: _StopFlag, time_limit: Optional[float], t_start: float,
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
            if _all_true(stop.requested or over_time, d, self.dev):
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
            stored = _resolved_sections(base)
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
