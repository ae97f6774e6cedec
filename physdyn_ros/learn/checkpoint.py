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
"""Checkpoints: one torch file holding everything needed to resume training or to predict.

Contents (a plain dict, loadable with torch.load(weights_only=True), so loading never runs pickled code):
    format, version         "physdyn-checkpoint", FORMAT_VERSION
    model_id                "<config name>-<sha256 of the weights, 12 hex>"
    config                  the full resolved config (model, loss, train, data sections)
    model                   state_dict (weights + normalisation buffer)
    normalization           the train-split statistics (also inside the state_dict; here for reading)
    dataset                 identity of the training data: path, manifest sha256, the manifest itself
    optimizer, scheduler    state_dicts (None in an inference-only export)
    rng                     python / numpy / torch (+ cuda) generator states
    progress                {"epoch", "batch", "step", "best_metric", "best_epoch"}
    torch_version, created
Writes are atomic (temporary file in the same folder, fsync, os.replace): a crash never leaves half a file.
"""
from __future__ import annotations

import hashlib
import os
import random
import time
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch

from ..data.format import atomic_write
from .model import DynamicsModel, ModelConfig

FORMAT = "physdyn-checkpoint"
FORMAT_VERSION = 1
_REQUIRED = ("format", "version", "model_id", "config", "model", "normalization")


class CheckpointError(RuntimeError):
    """A checkpoint file that cannot be used: corrupt, not a checkpoint, or incompatible with this code."""


def weights_digest(state_dict: dict[str, torch.Tensor]) -> str:
    h = hashlib.sha256()
    for name in sorted(state_dict):
        t = state_dict[name].detach().cpu().contiguous()
        h.update(name.encode())
        h.update(t.numpy().tobytes() if t.dtype != torch.bfloat16 else t.float().numpy().tobytes())
    return h.hexdigest()


def rng_state() -> dict[str, Any]:
    """All generator states, in weights_only-loadable types (tensors, lists, ints)."""
    py = random.getstate()
    np_state: Any = np.random.get_state()  # the legacy tuple (name, keys, pos, has_gauss, cached_gaussian)
    state: dict[str, Any] = {
        "python": [py[0], list(py[1]), py[2]],
        "numpy": [np_state[0], torch.from_numpy(np_state[1].astype(np.int64)), int(np_state[2]),
                  int(np_state[3]), float(np_state[4])],
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def restore_rng(state: dict[str, Any]) -> None:
    py = state["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))
    n = state["numpy"]
    np.random.set_state((n[0], n[1].numpy().astype(np.uint32), n[2], n[3], n[4]))
    torch.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def _atomic_save(obj: dict[str, Any], path: Path) -> None:
    atomic_write(path, lambda fh: torch.save(obj, fh))


def save_checkpoint(path: str | os.PathLike, *, model: DynamicsModel, config: dict[str, Any],
                    dataset: dict[str, Any], optimizer: Optional[torch.optim.Optimizer] = None,
                    scheduler: Optional[Any] = None, progress: Optional[dict[str, Any]] = None,
                    include_rng: bool = True) -> str:
    """Write a checkpoint atomically; returns its model_id. Optimizer/scheduler None = inference-only file."""
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    model_id = f"{model.cfg.name}-{weights_digest(state)[:12]}"
    obj = {
        "format": FORMAT, "version": FORMAT_VERSION, "model_id": model_id, "config": config, "model": state,
        "normalization": model.normalization(), "dataset": dataset,
        "optimizer": optimizer.state_dict() if optimizer is not None else None,
        "scheduler": scheduler.state_dict() if scheduler is not None else None,
        "rng": rng_state() if include_rng else None, "progress": dict(progress or {}),
        "torch_version": str(torch.__version__), "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    _atomic_save(obj, Path(path))
    return model_id


def load_checkpoint(path: str | os.PathLike, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read and validate a checkpoint. FileNotFoundError if missing, CheckpointError if unusable."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        obj = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # torch.load raises many types for damaged files (zip, pickle, EOF, ...)
        if "Unsupported global" in str(exc):
            raise CheckpointError(f"checkpoint {path} holds Python objects other than plain data; refusing to "
                                  "unpickle it (not a physdyn checkpoint, or from an untrusted source)") from exc
        raise CheckpointError(f"checkpoint {path} is corrupt or not a torch file ({type(exc).__name__})") from exc
    if not isinstance(obj, dict) or obj.get("format") != FORMAT:
        kind = obj.get('format') if isinstance(obj, dict) else type(obj).__name__
        raise CheckpointError(f"{path} is not a physdyn checkpoint (format {kind!r})")
    if obj.get("version") != FORMAT_VERSION:
        raise CheckpointError(f"{path}: checkpoint format version {obj.get('version')} is not supported by this "
                              f"code (version {FORMAT_VERSION}); retrain or use a matching physdyn_ros release")
    missing = [k for k in _REQUIRED if k not in obj]
    if missing:
        raise CheckpointError(f"{path}: checkpoint lacks {missing}")
    return obj


def build_model(ckpt: dict[str, Any], path: str | os.PathLike = "<checkpoint>") -> DynamicsModel:
    """The model stored in a loaded checkpoint (weights and normalisation restored), in eval mode."""
    try:
        cfg = ModelConfig.from_dict(dict(ckpt["config"]["model"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: incompatible model config: {exc}") from exc
    model = DynamicsModel(cfg)
    stored = ckpt["model"].get("topple.mean") if isinstance(ckpt.get("model"), dict) else None
    if model.topple is not None and stored is not None and tuple(stored.shape) != tuple(model.topple.mean.shape):
        raise CheckpointError(
            f"{path}: its topple head was fitted on {stored.shape[0]} inputs, this version computes "
            f"{model.topple.in_dim} (the support descriptors changed); refit the head: physdyn fit-topple "
            f"--checkpoint {path} --data DATASET --out NEW.pt")
    try:
        model.load_state_dict(ckpt["model"], strict=True)
    except RuntimeError as exc:
        raise CheckpointError(f"{path}: weights do not fit the model config: {str(exc).splitlines()[0]}") from exc
    return model.eval()


def load_model(path: str | os.PathLike,
               map_location: str | torch.device = "cpu") -> tuple[DynamicsModel, dict[str, Any]]:
    """Convenience: (model in eval mode, checkpoint dict)."""
    ckpt = load_checkpoint(path, map_location)
    return build_model(ckpt, path), ckpt


def export_inference(src: str | os.PathLike, dst: str | os.PathLike) -> str:
    """Copy a training checkpoint without optimizer, scheduler and RNG state (what ships as models/default.pt)."""
    ckpt = load_checkpoint(src)
    model = build_model(ckpt, src)
    return save_checkpoint(dst, model=model, config=ckpt["config"], dataset=ckpt.get("dataset", {}),
                           progress=ckpt.get("progress"), include_rng=False)
