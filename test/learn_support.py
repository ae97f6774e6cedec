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
"""Shared helpers of the learning tests: a tiny REAL dataset (made once per test process by the real generator,
physdyn_ros.sim.generate), tiny model configs and random-weight checkpoints."""
from __future__ import annotations

import argparse
import atexit
import copy
import functools
import shutil
import tempfile
from pathlib import Path
from typing import Any

from conftest import ROOT

FIXTURES = ROOT / "test" / "fixtures"
REGRESSION_DATA = FIXTURES / "regression_data"


@functools.lru_cache(maxsize=None)
def tiny_dataset() -> Path:
    """120 simulations of 12 box / cylinder / bottle shapes (61 frames), object-level splits; ~2 s to make.

    Made once per pytest process with the real generator (convex-hull collisions: no V-HACD) and removed at exit.
    """
    from physdyn_ros.sim import generate as gen

    root = Path(tempfile.mkdtemp(prefix="physdyn-learn-test-"))
    atexit.register(shutil.rmtree, root, ignore_errors=True)
    ns = argparse.Namespace(config=None, categories="box,cylinder,bottle", num_sims=120, shapes_per_category=4,
                            seed=0, shard_size=60, num_frames=61, collision="hull", test_fraction=0.25)
    gen.generate(root / "data", gen.resolve_params(ns), workers=1, progress=False)
    return root / "data"


TINY_CONFIG: dict[str, Any] = {
    "model": {"name": "tiny", "num_points": 64, "pointnet": [32, 64], "shape_mlp": [32, 8], "hidden_size": 32,
              "num_layers": 2, "max_horizon": 80},
    "loss": {"eps": 0.05},
    "train": {"seed": 0, "epochs": 2, "batch_size": 16, "window": 10, "lr": 0.003, "lr_decay_every": 100000,
              "grad_clip": 1.0, "val_windows_per_sim": 1, "val_rollout_horizon": 20, "threads": 1,
              "checkpoint_every_s": 1e9},
}


def tiny_config(**sections: dict[str, Any]) -> dict[str, Any]:
    """TINY_CONFIG with per-section updates, resolved like `physdyn train` does."""
    from physdyn_ros.learn.config import resolve_config

    raw = copy.deepcopy(TINY_CONFIG)
    for name, values in sections.items():
        raw.setdefault(name, {}).update(values)
    return resolve_config(raw)


def random_checkpoint(path: Path, cell: str = "lstm", seed: int = 0) -> Path:
    """A checkpoint of the tiny architecture with random weights and plausible normalisation."""
    import torch

    from physdyn_ros.learn.checkpoint import save_checkpoint
    from physdyn_ros.learn.model import STAT_KEYS, DynamicsModel, ModelConfig

    cfg = tiny_config(model={"cell": cell})
    torch.manual_seed(seed)
    stats = dict(zip(STAT_KEYS, (0.5, 8.0, 0.2, 4.0, 0.03, 0.5, 0.15)))
    model = DynamicsModel(ModelConfig.from_dict(cfg["model"]), stats)
    save_checkpoint(path, model=model, config=cfg, dataset={}, include_rng=False)
    return path
