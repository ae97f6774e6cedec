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
"""The batch-1 C kernel (src/rollout1.c through learn/native.py) against the numpy kernel it replaces.

The C kernel computes numpy_lstm_rollout's function in another summation order and with its own float32 tanh,
so the two agree to float32 rounding, not bit for bit: these tests bound the difference on the shipped model
(with and without observed steps) and on small LSTMs of other sizes (one and three layers, a hidden size whose
gates fill a partial column panel, no prior), check that the Predictor's decisions do not move, and that the
kernel choice (PHYSDYN_BATCH1_KERNEL) does what it says, including its refusals.
"""
from __future__ import annotations

import platform

import numpy as np
import pytest
import torch

from physdyn_ros.learn import kernels, native
from physdyn_ros.learn.prior import prior_constants

#: float32 rounding over a 60-step closed loop: relative to each output column's largest magnitude
REL = 2e-4


def _close(a: np.ndarray, b: np.ndarray) -> float:
    """The largest difference relative to each column's magnitude (at least 1)."""
    scale = np.maximum(np.abs(b).max(axis=0), 1.0)
    return float((np.abs(a - b) / scale).max())


def _kernel_of(model) -> dict:
    with torch.inference_mode():
        return model._kernel(model._fast())


def _compare(kernel: dict, feature: np.ndarray, x0: np.ndarray, x_obs: np.ndarray, prior: tuple | None):
    """Both kernels on one push: (C raw, C inputs), (numpy raw, numpy inputs)."""
    bias0 = feature @ kernel["np_w_feature"] + kernel["np_b0"]
    w0 = kernel["np_w0"].copy()
    w0[6] = bias0
    ref = kernels.numpy_lstm_rollout(x0, x_obs, w0, kernel["np_w"], kernel["np_head"], 60, prior)
    got = native.c_lstm_rollout(x0, x_obs, bias0, kernel, kernel["np_head"], 60, prior)
    return got, ref


needs_c = pytest.mark.skipif(not native.use_c(), reason=f"the C kernel is not in use here: {native.status()}")


def test_the_c_kernel_is_built_and_used_on_this_machine(monkeypatch):
    """setup.sh builds it (CMakeLists.txt); on an x86-64 CPU with AVX2 and FMA batch 1 must run it."""
    from physdyn_ros.learn.precision import cpu_flags

    monkeypatch.delenv(native.ENV, raising=False)
    if platform.machine() not in ("x86_64", "AMD64") or not {"avx2", "fma"} <= cpu_flags():
        pytest.skip("not an x86-64 CPU with AVX2 and FMA")
    assert native.use_c(), native.status()


def _pushes(n: int, seed: int):
    """Clouds of catalogue shapes resting on the table and pushes of 0.3-1.6 m/s with up to 5 rad/s of spin."""
    from physdyn_ros.shapes import generate_shapes

    rng = np.random.default_rng(seed)
    shapes = [s for cat in ("box", "cylinder", "bottle", "mug") for s in generate_shapes(cat, 3, seed=seed)]
    for k in range(n):
        shape = shapes[k % len(shapes)]
        cloud = np.asarray(shape.points) - [0.0, 0.0, float(shape.vertices[:, 2].min())]
        speed, az = rng.uniform(0.3, 1.6), rng.uniform(-np.pi, np.pi)
        yield cloud, np.array([speed * np.cos(az), speed * np.sin(az), 0.0]), np.array([0, 0, rng.uniform(-5, 5)])


@needs_c
@pytest.mark.parametrize("observed", [0, 4])
def test_the_shipped_model_agrees_with_the_numpy_kernel(observed):
    from physdyn_ros.learn.frames import world_to_c
    from physdyn_ros.predictor import Predictor

    pred = Predictor.load(precision="fp32")
    model = pred._model
    kernel = _kernel_of(model)
    worst = 0.0
    for cloud, v, w in _pushes(24, observed):
        code = pred.encode(cloud)
        feature = np.asarray(code.feature[:model.feature_dim], np.float32)
        x0 = (np.concatenate([world_to_c(v, code.heading), world_to_c(w, code.heading)]) / kernel["np_in"])
        x0 = x0.astype(np.float32)
        x_obs = (x0 * np.linspace(0.9, 0.6, observed)[:, None]).astype(np.float32)
        with torch.inference_mode():
            decel = torch.stack(model._prior_decel(torch.from_numpy(feature[None])), -1).numpy()[0]
        prior = prior_constants(decel[0], decel[1], kernel["np_in"], kernel["np_out"], kernel["np_gain"],
                                coupling=float(decel[2]))
        (raw, xs), (raw_ref, xs_ref) = _compare(kernel, feature, x0, x_obs, prior)
        assert raw.shape == raw_ref.shape == (60, 13) and xs.shape == xs_ref.shape == (61, 6)
        assert np.array_equal(xs[1:observed + 1], x_obs)  # observed inputs are taken as given
        worst = max(worst, _close(raw, raw_ref), _close(xs, xs_ref))
    assert 0.0 < worst < REL, worst  # distinct code (equal bits throughout would be a surprise), within rounding


@needs_c
@pytest.mark.parametrize("layers,hidden,prior", [(1, 20, "sliding"), (3, 16, "none"), (2, 40, "coupled")])
def test_other_sizes_agree_with_the_numpy_kernel(layers, hidden, prior):
    """Partial column panels (4 H not a multiple of 64), one and three layers, no prior."""
    from test_rollout_identity import TINY_LSTM, _tiny_model

    cfg = dict(TINY_LSTM, hidden_size=hidden, num_layers=layers, input_skip=True, geometry=True, prior=prior)
    kernel = _kernel_of(_tiny_model(cfg, None, "", layers * 100 + hidden))  # seeded random weights
    rng = np.random.default_rng(hidden)
    feature = rng.normal(0, 1, kernel["np_w_feature"].shape[0]).astype(np.float32)
    x0 = rng.normal(0, 1, 6).astype(np.float32)
    args = None if prior == "none" else prior_constants(4.9, 50.0, kernel["np_in"], kernel["np_out"],
                                                        kernel["np_gain"], coupling=float(prior == "coupled"))
    (raw, xs), (raw_ref, xs_ref) = _compare(kernel, feature, x0, np.zeros((0, 6), np.float32), args)
    assert _close(raw, raw_ref) < REL and _close(xs, xs_ref) < REL


@needs_c
def test_the_predictor_decides_the_same_through_either_kernel(monkeypatch):
    """Trajectories within float32 rounding and the same topple decisions, through Predictor.rollout."""
    from physdyn_ros.predictor import Predictor

    pred = Predictor.load(precision="fp32")
    for k, (cloud, v, w) in enumerate(_pushes(12, 5)):
        out = {}
        for choice in ("numpy", "c"):
            monkeypatch.setenv(native.ENV, choice)
            out[choice] = pred.rollout(cloud, v, w, 60)
        a, b = out["numpy"], out["c"]
        assert np.abs(a.positions - b.positions).max() < 1e-4, k  # 0.1 mm
        assert np.abs(a.orientations - b.orientations).max() < 1e-4, k
        assert (a.topple_probability > 0.5) == (b.topple_probability > 0.5), k
        assert abs(a.topple_probability - b.topple_probability) < 1e-4, k


def test_the_kernel_choice_and_its_refusals(monkeypatch):
    monkeypatch.setenv(native.ENV, "numpy")
    assert not native.use_c()
    monkeypatch.setenv(native.ENV, "fortran")
    with pytest.raises(ValueError, match="PHYSDYN_BATCH1_KERNEL='fortran': expected one of auto, numpy, c"):
        native.use_c()
    from physdyn_ros.predictor import Predictor

    with pytest.raises(ValueError, match="PHYSDYN_BATCH1_KERNEL='fortran'"):  # refused at load, not per request
        Predictor.load()
    # a library without the kernel's symbols (a stale or foreign build) is passed over, not a crash
    foreign = native.Path(np._core._multiarray_umath.__file__)  # a shared library without the kernel
    monkeypatch.setattr(native, "library_paths", lambda: [foreign])
    native.library.cache_clear()
    try:
        monkeypatch.setenv(native.ENV, "auto")
        assert not native.use_c() and "undefined symbol" in native.status()
    finally:
        native.library.cache_clear()
    # a library that is not there: "c" names why, "auto" falls back to numpy
    monkeypatch.setattr(native, "library_paths", lambda: [native.Path("/nonexistent/lib") / native.LIBRARY])
    native.library.cache_clear()
    try:
        monkeypatch.setenv(native.ENV, "c")
        with pytest.raises(ValueError, match="cannot load: libphysdyn_rollout1.so is not built"):
            native.use_c()
        monkeypatch.setenv(native.ENV, "auto")
        assert not native.use_c()
    finally:
        monkeypatch.undo()
        native.library.cache_clear()


@needs_c
def test_weights_that_do_not_fit_the_layout_are_refused():
    from physdyn_ros.predictor import Predictor

    kernel = _kernel_of(Predictor.load(precision="fp32")._model)
    bias0 = np.zeros(kernel["np_b0"].shape, np.float32)
    with pytest.raises(ValueError, match="do not fit"):
        native.c_lstm_rollout(np.zeros(5, np.float32), np.zeros((0, 6), np.float32), bias0, kernel,
                              kernel["np_head"], 10)
    with pytest.raises(ValueError, match="do not fit"):
        native.c_lstm_rollout(np.zeros(6, np.float32), np.zeros((0, 6), np.float32), bias0, kernel,
                              kernel["np_head"][:-1], 10)
    with pytest.raises(ValueError, match="do not fit"):  # a head too narrow for the prior's writes
        native.c_lstm_rollout(np.zeros(6, np.float32), np.zeros((0, 6), np.float32), bias0, kernel,
                              np.ascontiguousarray(kernel["np_head"][:, :12]), 10)
