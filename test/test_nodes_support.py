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
"""Helpers shared by the node tests (a small random checkpoint, spinning nodes in a background executor).

Imported by test_nodes_*.py; its own test checks that the helper checkpoint loads through the real loader.
"""
from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Callable

import pytest

#: Normalisation scales that keep a random model's outputs at tabletop size (cm per step, not metres).
TINY_STATS = {"vel": 1.0, "angvel": 3.0, "d_vel": 0.02, "d_angvel": 0.05, "d_pos": 0.01, "d_rot": 0.02,
              "cloud": 0.05}


def make_tiny_checkpoint(path: Path, seed: int = 0, name: str = "tiny-test", com_head: bool = False) -> str:
    """A randomly initialised, small model saved with the learn package's own checkpoint writer (com_head: with a
    centre-of-mass head, like the shipped model's)."""
    import torch

    from physdyn_ros.learn.checkpoint import save_checkpoint
    from physdyn_ros.learn.model import DynamicsModel, ModelConfig

    torch.manual_seed(seed)
    cfg = ModelConfig(name=name, num_points=128, pointnet=(16, 32), shape_mlp=(16, 16), hidden_size=32,
                      num_layers=1, com_head=com_head)
    return save_checkpoint(path, model=DynamicsModel(cfg, TINY_STATS), config={"model": cfg.to_dict()},
                           dataset={}, include_rng=False)


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("models") / "tiny.pt"
    make_tiny_checkpoint(path)
    return path


class Spinner:
    """Spin nodes in a MultiThreadedExecutor on a background thread; destroys them on exit."""

    def __init__(self, *nodes, threads: int = 4) -> None:
        from rclpy.executors import MultiThreadedExecutor

        self.nodes = list(nodes)
        self.executor = MultiThreadedExecutor(num_threads=threads)
        for n in self.nodes:
            self.executor.add_node(n)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)

    def _spin(self) -> None:
        from physdyn_ros.ros.run import spin_once

        # spin_once in a loop (not spin): stopping then never races the executor's own shutdown.
        while not self._stop.is_set():
            spin_once(self.executor, 0.05)

    def __enter__(self) -> "Spinner":
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self.thread.join(10.0)
        # Jazzy's Executor.shutdown does not wait for running callbacks (its wait sits behind an always-false
        # test), so wait for them here before the nodes and the executor's guard condition are destroyed.
        self.executor._work_tracker.wait(10.0)
        # Tasks that found their mutually exclusive group busy still touch the executor's guard condition.
        wait_for(lambda: all(f.done() for f in list(self.executor._futures)), 5.0)
        self.executor.shutdown(timeout_sec=5.0)
        for n in self.nodes:
            n.destroy_node()


def wait_for(predicate: Callable[[], object], timeout: float = 10.0, step: float = 0.01) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return bool(predicate())


def call(client, request, timeout: float = 20.0):
    """Call a service from the test thread while a Spinner spins the client's node."""
    assert client.wait_for_service(timeout_sec=timeout), f"service {client.srv_name} not available"
    future = client.call_async(request)
    assert wait_for(future.done, timeout), f"no answer from {client.srv_name}"
    return future.result()


def test_tiny_checkpoint_loads_with_the_predictor(tiny_model):
    from physdyn_ros.predictor import Predictor

    pred = Predictor.load(tiny_model, threads=1)
    assert pred.model_id.startswith("tiny-test-") and pred.feature_dim == 16 and pred.num_points == 128
