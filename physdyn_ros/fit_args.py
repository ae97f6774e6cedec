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
"""The arguments and the pushes of the commands that fit a file beside a checkpoint on a dataset's pushes
(`physdyn fit-topple-fusion`, `physdyn fit-spread`)."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["add_fit_arguments", "fit_pushes"]


def add_fit_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", required=True, help="dataset to fit on")
    parser.add_argument("--checkpoint", default=None, help="default: the shipped model")
    parser.add_argument("--splits", nargs="+", default=["test"],
                        help="splits to fit on (all three for a dataset made for fitting)")
    parser.add_argument("--max-sequences", type=int, default=1500)
    parser.add_argument("--out", type=Path, default=None, help="default: beside the checkpoint")


def fit_pushes(args: argparse.Namespace, minimum: int) -> tuple[Path, Any, np.ndarray]:
    """The checkpoint (the shipped model by default), the dataset's simulations of args.splits and the index of
    at most args.max_sequences pushes evenly spaced over them; ValueError for fewer than `minimum`."""
    from .learn.windows import load_sims
    from .resources import DEFAULT_MODEL

    if args.max_sequences < minimum:
        raise ValueError(f"--max-sequences must be at least {minimum}, got {args.max_sequences}")
    ckpt = Path(args.checkpoint) if args.checkpoint else DEFAULT_MODEL
    sims = load_sims(args.data, list(args.splits))
    return ckpt, sims, np.linspace(0, len(sims) - 1, min(args.max_sequences, len(sims))).astype(np.int64)
