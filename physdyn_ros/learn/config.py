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
"""A run's config: the train and data sections, and a whole config (model, loss, train, data) resolved from a
YAML file, `section.key=value` overrides or a checkpoint's stored sections.

The model and loss sections are defined beside what they configure (model.ModelConfig, losses.LossConfig).
"""
from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Optional

import yaml

from .losses import LossConfig
from .model import ModelConfig
from .sections import known_keys

#: Validation metrics a run may select its best checkpoint by.
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


def section(cls: type, data: Optional[dict[str, Any]], name: str) -> Any:
    """The dataclass `cls` of one config section `name` (its keys checked: sections.known_keys)."""
    return cls(**known_keys(cls, data or {}, name))


def resolve_config(raw: dict[str, Any]) -> dict[str, Any]:
    """Validate a config dict (model / loss / train / data sections) and fill in defaults."""
    model = ModelConfig.from_dict(dict(raw.get("model") or {}))  # first: it names a removed option it needs
    unknown = sorted(set(raw) - {"model", "loss", "train", "data"})
    if unknown:
        raise ValueError(f"unknown config sections {unknown} (expected model, loss, train, data)")
    loss = LossConfig.from_dict(dict(raw.get("loss") or {}))
    train = section(TrainConfig, raw.get("train"), "train")
    data = section(DataConfig, raw.get("data"), "data")
    return {"model": model.to_dict(), "loss": loss.to_dict(), "train": asdict(train), "data": asdict(data)}


def resolved_sections(config: dict[str, Any]) -> dict[str, Any]:
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
