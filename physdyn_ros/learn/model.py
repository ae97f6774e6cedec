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
"""The dynamics network (Rempe et al. 2020): its config, its layers and its entry points.

    cloud (B, P, 3) in frame C --PointNet--> global feature --MLP--> shape feature f (B, F), once per object
    per step t:  [v_t, w_t, f] (6 + F) --LSTM (or the paper's memoryless MLP baseline)--> 13 numbers:
                 d_vel (3), d_angvel (3), d_pos (3), d_rot (3, world-fixed axis-angle in C), topple logit (1)
    roll-out:    v_{t+1} = v_t + d_vel_t and w_{t+1} = w_t + d_angvel_t are fed back as the next input
                 (rollout_raw / rollout / rollout_arrays; the loops themselves are learn/kernels.py).

All tensors entering or leaving the public methods are physical SI quantities in frame C (learn/frames.py);
the normalisation scales (train-split statistics, learn/windows.py) live in the model as a buffer, so a
checkpoint is self-contained.

Normalisation layers: the paper's PointNet uses BatchNorm (config/model_paper.yaml reproduces it). The shipped
model uses LayerNorm: it normalises each point (and each sample) by itself, so training and inference compute
the same function, a batch of one equals one sample of a batch (the planner batches roll-outs), there are no
running statistics to drift between random training windows and evaluation, and DDP needs no SyncBatchNorm.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Optional, Tuple

import numpy as np
import torch
from torch import Tensor, nn

from ..conventions import GRAVITY
from .kernels import OUT_DIM, fused_rollout, kernel_weights, lstm_rollout, lstm_weights, mlp_rollout, numpy_rollout
from .precision import resolve_precision
from .prior import MIN_RADIUS, prior_raw
from .sections import known_keys
from .topple import ToppleHead

#: The normalisation scales, in buffer order. Each is one scalar per vector quantity (an RMS norm), so a
#: rotation about z commutes with normalisation and relative losses keep their geometric meaning.
STAT_KEYS = ("vel", "angvel", "d_vel", "d_angvel", "d_pos", "d_rot", "cloud")
CELLS = ("lstm", "mlp")
NORMS = ("batch", "layer", "none")
PRIORS = ("none", "sliding", "coupled")
#: Cloud descriptors appended to the shape feature (model.geometry), in units of the cloud scale, from the cloud in
#: C centred at its centroid: RMS horizontal radius (spin friction's lever arm), height, height of the centroid
#: over the lowest point, largest horizontal radius.
GEOMETRY = ("radius", "height", "centroid_height", "reach")


@dataclass
class ModelConfig:
    """Architecture (the `model:` section of a config YAML)."""

    name: str = "default"
    num_points: int = 256  # points fed to PointNet (clouds are resampled to this)
    pointnet: Tuple[int, ...] = (64, 64, 128, 256)  # shared per-point MLP widths; the last is the pooled size
    norm: str = "layer"  # batch | layer | none, in PointNet and the shape MLP
    norm_eps: float = 1e-5
    bn_momentum: float = 0.1  # torch convention (= 1 - TF decay)
    shape_mlp: Tuple[int, ...] = (128, 64, 16)  # after max-pooling; the last width is the shape feature size
    shape_final_activation: bool = False  # paper: norm + ReLU on the last layer too (feature >= 0)
    cell: str = "lstm"  # lstm | mlp (the paper's memoryless baseline)
    hidden_size: int = 128
    num_layers: int = 2  # LSTM layers
    mlp_layers: int = 5  # fully connected layers of the MLP baseline (incl. output)
    mlp_activation: str = "tanh"
    forget_bias: float = 1.0  # TF LSTMCell default, used by the original
    # A linear map from the step's normalised [v, w] straight to the outputs, added to the recurrent head (zero at
    # start). d_pos ~ v dt and d_rot ~ w dt are linear in the input, but a head on tanh-bounded LSTM states
    # learns large increments slowly: without it fast pushes travel far short of the data, even with the true
    # velocities fed. The paper has no such path; model_paper.yaml keeps it off.
    input_skip: bool = False
    # Physically meaningful inputs computed from the cloud (GEOMETRY: lever arm, height, centroid height, reach),
    # appended to the learned shape feature: what decides sliding and toppling, and exact for any shape family.
    geometry: bool = False
    # "sliding": the outputs are a residual on Coulomb sliding (learn/prior.py; needs geometry for the lever
    # arm), with friction prior_friction. Zero residual at start = the analytic sliding baseline. "coupled": the
    # same with sliding and spinning sharing the friction (ellipsoidal limit surface, learn/prior.py).
    prior: str = "none"
    prior_friction: float = 0.5
    # A head that estimates the centre of mass from the cloud (relative to its centroid, in C): the start of a
    # roll-out when only one side of the object is seen.
    com_head: bool = False
    # A whole-push topple head (learn/topple.py): one calibrated probability per push from the shape feature,
    # support-polygon descriptors and the initial twist; fitted after the dynamics (`physdyn fit-topple`).
    topple_head: bool = False
    topple_hidden: int = 64
    topple_members: int = 5
    max_horizon: int = 150  # longest roll-out the Predictor accepts (10 s at 15 Hz)

    def __post_init__(self) -> None:
        self.pointnet = tuple(int(w) for w in self.pointnet)
        self.shape_mlp = tuple(int(w) for w in self.shape_mlp)
        if self.norm not in NORMS:
            raise ValueError(f"model.norm must be one of {NORMS}, got {self.norm!r}")
        if self.cell not in CELLS:
            raise ValueError(f"model.cell must be one of {CELLS}, got {self.cell!r}")
        if self.mlp_activation not in ("tanh", "relu"):
            raise ValueError(f"model.mlp_activation must be tanh or relu, got {self.mlp_activation!r}")
        if not self.pointnet or not self.shape_mlp or min(self.pointnet + self.shape_mlp) < 1:
            raise ValueError("model.pointnet and model.shape_mlp need at least one positive width each")
        if self.prior not in PRIORS:
            raise ValueError(f"model.prior must be one of {PRIORS}, got {self.prior!r}")
        if self.prior != "none" and not self.geometry:
            raise ValueError(f"model.prior {self.prior} needs model.geometry: true (the lever arm of spin friction)")
        if not 0.0 < float(self.prior_friction) <= 2.0:
            raise ValueError(f"model.prior_friction must be in (0, 2], got {self.prior_friction}")
        for key in ("num_points", "hidden_size", "num_layers", "mlp_layers", "max_horizon", "topple_hidden",
                    "topple_members"):
            if int(getattr(self, key)) < 1:
                raise ValueError(f"model.{key} must be >= 1, got {getattr(self, key)}")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ModelConfig":
        return cls(**known_keys(cls, data, "model"))

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["pointnet"], d["shape_mlp"] = list(self.pointnet), list(self.shape_mlp)
        return d


def _norm(kind: str, width: int, cfg: ModelConfig) -> nn.Module:
    if kind == "batch":
        return nn.BatchNorm1d(width, eps=cfg.norm_eps, momentum=cfg.bn_momentum)
    if kind == "layer":
        return nn.LayerNorm(width, eps=cfg.norm_eps)
    return nn.Identity()


class _Block(nn.Module):
    """Linear -> norm -> ReLU on (..., C); BatchNorm sees all leading dims as its batch (as TF's conv BN)."""

    def __init__(self, c_in: int, c_out: int, cfg: ModelConfig, activation: bool = True) -> None:
        super().__init__()
        self.linear = nn.Linear(c_in, c_out)
        self.norm = _norm(cfg.norm, c_out, cfg) if activation else nn.Identity()
        self.activation = activation

    def forward(self, x: Tensor) -> Tensor:
        x = self.linear(x)
        if isinstance(self.norm, nn.BatchNorm1d):
            x = self.norm(x.reshape(-1, x.shape[-1])).reshape(x.shape)
        else:
            x = self.norm(x)
        return torch.relu(x) if self.activation else x


class DynamicsModel(nn.Module):
    """Shape encoder + state predictor. See the module docstring for the data flow."""

    scales: Tensor  # buffer (STAT_KEYS order): the normalisation scales

    def __init__(self, cfg: ModelConfig, stats: Optional[dict[str, float]] = None) -> None:
        super().__init__()
        self.cfg = cfg
        widths = (3,) + cfg.pointnet
        self.pointnet = nn.Sequential(*[_Block(a, b, cfg) for a, b in zip(widths[:-1], widths[1:])])
        mlp = (cfg.pointnet[-1],) + cfg.shape_mlp
        n = len(cfg.shape_mlp)
        self.shape_mlp = nn.Sequential(*[
            _Block(a, b, cfg, activation=(i < n - 1 or cfg.shape_final_activation))
            for i, (a, b) in enumerate(zip(mlp[:-1], mlp[1:]))])
        self.learned_dim = cfg.shape_mlp[-1]
        self.feature_dim = self.learned_dim + (len(GEOMETRY) if cfg.geometry else 0)
        in_dim = 6 + self.feature_dim
        if cfg.cell == "lstm":
            self.lstm = nn.LSTM(in_dim, cfg.hidden_size, cfg.num_layers, batch_first=True)
            self.head = nn.Linear(cfg.hidden_size, OUT_DIM)
        else:
            act = nn.Tanh if cfg.mlp_activation == "tanh" else nn.ReLU
            dims = [in_dim] + [cfg.hidden_size] * (cfg.mlp_layers - 1)
            layers: list[nn.Module] = []
            for a, b in zip(dims[:-1], dims[1:]):
                layers += [nn.Linear(a, b), act()]
            self.mlp = nn.Sequential(*layers, nn.Linear(dims[-1], OUT_DIM))
        self.skip = nn.Linear(6, OUT_DIM, bias=False) if cfg.input_skip else None
        self.com = nn.Linear(self.feature_dim, 3) if cfg.com_head else None
        self.topple = (ToppleHead(self.feature_dim, cfg.topple_hidden, cfg.topple_members)
                       if cfg.topple_head else None)
        self.register_buffer("scales", torch.ones(len(STAT_KEYS)))
        self._reset_parameters()
        if stats is not None:
            self.set_normalization(stats)
        self._cache_key: Optional[tuple] = None
        self._cache: Optional[dict[str, Any]] = None
        self._cache_params: Optional[list[Tensor]] = None

    # ----------------------------------------------------------------------------------------------- setup
    def _reset_parameters(self) -> None:
        """Xavier weights and zero biases (the original's initialisers); LSTM forget gates start at forget_bias."""
        for name, p in self.named_parameters():
            if p.dim() >= 2:
                nn.init.xavier_uniform_(p)
            elif name.endswith("bias") or "bias_" in name:
                nn.init.zeros_(p)
        if self.cfg.cell == "lstm":
            h = self.cfg.hidden_size
            for layer in range(self.cfg.num_layers):
                getattr(self.lstm, f"bias_ih_l{layer}").data[h:2 * h] = self.cfg.forget_bias
        if self.skip is not None:
            nn.init.zeros_(self.skip.weight)  # start as the paper's network; the path grows where it helps
        if self.cfg.prior != "none":
            # a zero residual: the untrained network is exactly the prior (the motion part; topple logit 0)
            last = self.head if self.cfg.cell == "lstm" else self.mlp[-1]
            assert isinstance(last, nn.Linear)
            nn.init.zeros_(last.weight)

    def set_normalization(self, stats: dict[str, float]) -> None:
        missing = [k for k in STAT_KEYS if k not in stats]
        if missing:
            raise ValueError(f"normalization stats lack {missing}")
        values = torch.tensor([float(stats[k]) for k in STAT_KEYS])
        if not torch.all(torch.isfinite(values)) or torch.any(values <= 0):
            scales = dict(zip(STAT_KEYS, values.tolist()))
            raise ValueError(f"normalization scales must be finite and positive: {scales}")
        self.scales.copy_(values)

    def normalization(self) -> dict[str, float]:
        return dict(zip(STAT_KEYS, self.scales.tolist()))

    def _scale(self, key: str) -> Tensor:
        return self.scales[STAT_KEYS.index(key)]

    def _scale_vectors(self) -> dict[str, Tensor]:
        """Per-channel views of the scales: inputs (6,), outputs (13,; logit 1), and the feedback gain (6,)
        that turns a normalised d_vel/d_angvel output into an increment of the normalised input."""
        s = self.scales
        inp = s[[0, 0, 0, 1, 1, 1]]
        out = torch.cat([s[[2, 2, 2, 3, 3, 3, 4, 4, 4, 5, 5, 5]], s.new_ones(1)])
        return {"in": inp, "out": out, "gain": out[:6] / inp}

    def _fast(self) -> dict[str, Any]:
        """Scale vectors and (LSTM) kernel weights: transposed, gates reordered. Rebuilt whenever autograd is
        on (training must see the live parameters); otherwise cached until a parameter changes."""
        if not torch.is_grad_enabled():
            if self._cache_params is None:
                # what _build_fast reads (not the encoder's parameters: fewer to check on every roll-out)
                used: list[Optional[nn.Module]] = ([self.lstm, self.head] if self.cfg.cell == "lstm"
                                                   else [self.mlp])
                self._cache_params = [p for m in used + [self.skip] if m is not None
                                      for p in m.parameters()]
                self._cache_params.append(self.scales)
            key = tuple((p.data_ptr(), p._version) for p in self._cache_params)
            if self._cache is not None and self._cache_key == key:
                return self._cache
        if torch.is_grad_enabled():
            return self._build_fast()
        with torch.inference_mode(False), torch.no_grad():  # normal tensors: usable in and out of inference mode
            self._cache, self._cache_key = self._build_fast(), key
        return self._cache

    def _build_fast(self) -> dict[str, Any]:
        """The scale vectors and, for the LSTM, the roll-out kernel's weights (kernels.lstm_weights)."""
        fast: dict[str, Any] = self._scale_vectors()
        if self.cfg.cell == "lstm":
            fast.update(lstm_weights(self.lstm, self.head, self.skip))
        return fast

    def _kernel(self, fast: dict[str, Any]) -> dict[str, Any]:
        """Weights of the inference kernels (kernels.kernel_weights), derived from `fast` once and kept in it:
        `fast` is the cached dict whenever autograd is off, so they are rebuilt only when a parameter changes."""
        kernel = fast.get("kernel")
        if kernel is None:
            with torch.inference_mode(False), torch.no_grad():
                kernel = kernel_weights(fast, self._scale("cloud").item())
            fast["kernel"] = kernel
        return kernel

    # --------------------------------------------------------------------------------------------- pieces
    def encode(self, cloud: Tensor) -> Tensor:
        """Shape feature (B, F) of clouds (B, P, 3) in frame C, metres, centred at their centroid."""
        scaled = cloud / self._scale("cloud")
        feature = self.shape_mlp(self.pointnet(scaled).max(dim=1).values)
        if not self.cfg.geometry:
            return feature
        r2 = (scaled[..., :2] * scaled[..., :2]).sum(-1)
        z = scaled[..., 2]
        zmin = z.min(dim=1).values
        geometry = torch.stack([r2.mean(1).sqrt(), z.max(dim=1).values - zmin, -zmin, r2.max(dim=1).values.sqrt()], -1)
        return torch.cat([feature, geometry], -1)

    def com_offset(self, feature: Tensor) -> Tensor:
        """Estimated centre of mass relative to the cloud's centroid (B, 3), metres in C (needs model.com_head)."""
        if self.com is None:
            raise ValueError("this model has no centre-of-mass head (model.com_head)")
        return self.com(feature) * self._scale("cloud")

    def com_estimate(self, feature: Tensor) -> Tensor:
        """com_offset, or zeros (the centroid itself) for a model without a centre-of-mass head (B, 3)."""
        return self.com_offset(feature) if self.com is not None else feature.new_zeros(len(feature), 3)

    def _prior_decel(self, feature: Tensor) -> Tuple[Tensor, Tensor, Tensor]:
        """(mu g, mu g / r, coupling) per object of the prior (prior.sliding_step), r from the feature's geometry
        (model.prior)."""
        radius = (feature[:, self.learned_dim] * self._scale("cloud")).clamp_min(MIN_RADIUS)
        decel = torch.full_like(radius, float(self.cfg.prior_friction) * GRAVITY)
        coupling = torch.full_like(radius, float(self.cfg.prior == "coupled"))
        return decel, decel / radius, coupling

    def _inputs(self, vel: Tensor, angvel: Tensor, fast: Optional[dict[str, Any]] = None) -> Tensor:
        scale = (fast or self._scale_vectors())["in"]
        return torch.cat([vel, angvel], -1) / scale

    def normalize_targets(self, d_vel: Tensor, d_angvel: Tensor, d_pos: Tensor, d_rot: Tensor) -> Tensor:
        """Physical increments (..., 3) each -> the network's normalised output space (..., 12)."""
        return torch.cat([d_vel, d_angvel, d_pos, d_rot], -1) / self._scale_vectors()["out"][:12]

    def denormalize(self, raw: Tensor, fast: Optional[dict[str, Any]] = None) -> dict[str, Tensor]:
        """Raw outputs (..., 13) -> physical increments in C and the topple logit."""
        phys = raw * (fast or self._scale_vectors())["out"]
        return {"d_vel": phys[..., 0:3], "d_angvel": phys[..., 3:6], "d_pos": phys[..., 6:9],
                "d_rot": phys[..., 9:12], "topple_logit": raw[..., 12]}

    def teacher_forced(self, feature: Tensor, vel: Tensor, angvel: Tensor) -> Tensor:
        """Raw outputs (B, T, 13) with the given (ground-truth) velocities (B, T, 3) fed at every step."""
        scales = self._scale_vectors()
        x = self._inputs(vel, angvel)
        x = torch.cat([x, feature[:, None, :].expand(-1, x.shape[1], -1)], -1)
        y = self.head(self.lstm(x)[0]) if self.cfg.cell == "lstm" else self.mlp(x)
        if self.skip is not None:
            y = y + self.skip(x[..., :6])
        if self.cfg.prior != "none":
            decel, spin, coupling = self._prior_decel(feature)
            p = prior_raw(x[..., :6], decel[:, None], spin[:, None], coupling[:, None], scales["in"], scales["out"])
            y = y + torch.cat([p, torch.zeros_like(p[..., :1])], -1)
        return y

    def rollout_raw(self, feature: Tensor, vel0: Tensor, angvel0: Tensor, steps: int,
                    obs_vel: Optional[Tensor] = None, obs_angvel: Optional[Tensor] = None,
                    fast: Optional[dict[str, Any]] = None, precision: str = "fp32") -> Tuple[Tensor, Tensor]:
        """Closed-loop roll-out in the network's normalised spaces.

        The kernel (learn/kernels.py): the LSTM with autograd on runs the differentiable lstm_rollout; without,
        the same function faster, numpy_lstm_rollout at batch 1 (float32 on the CPU), else fused_lstm_rollout,
        or bf16_lstm_rollout when `precision` resolves to bf16; the MLP baseline runs mlp_rollout.

        Args:
            feature: (B, F) shape features (encode).
            vel0, angvel0: (B, 3) the state at frame 0 in frame C (m/s, rad/s).
            steps: steps to roll out.
            obs_vel, obs_angvel: optional (B, K, 3) observed states of frames 1..K, fed instead of the model's
                own predictions ("steps in" = K + 1); both or neither.
            fast: the model's _fast() dict, when the caller has it.
            precision: "fp32" (default), "bf16" or "auto" (precision.resolve_precision: by the CPU's flags and the
                batch size) for the batched inference kernel; training (autograd), batch 1 and the MLP baseline
                always run in the model's dtype.

        Returns:
            Raw outputs (B, steps, 13) (denormalize turns them physical) and the normalised inputs used
            (B, steps + 1, 6).
        """
        fast = fast or self._fast()
        x0 = self._inputs(vel0, angvel0, fast)
        if obs_vel is None:
            x_obs = x0.new_zeros(x0.shape[0], 0, 6)
        else:
            assert obs_angvel is not None, "obs_vel and obs_angvel go together"
            x_obs = self._inputs(obs_vel, obs_angvel, fast)[:, :steps]
        prior = (torch.stack(self._prior_decel(feature), -1) if self.cfg.prior != "none"
                 else x0.new_zeros(0, 3))
        if self.cfg.cell == "mlp":
            return mlp_rollout(self.mlp, self.skip, feature, x0, x_obs, int(steps), prior, fast)
        if torch.is_grad_enabled():  # training / gradients: the differentiable kernel
            w_x = fast["w_x"]
            const0 = torch.addmm(fast["bias"][0], feature, w_x[0][6:])  # the feature term is constant in time
            return lstm_rollout(x0, x_obs, const0, [w_x[0][:6]] + w_x[1:], fast["w_h"], fast["bias"],
                                fast["w_out"], fast["b_out"], fast["w_skip"], fast["gain"], int(steps),
                                prior, fast["in"], fast["out"])
        kernel = self._kernel(fast)
        if x0.shape[0] == 1 and "np_w0" in kernel and x0.device.type == "cpu" and x0.dtype == torch.float32:
            raw_np, xs_np = numpy_rollout(kernel, feature.numpy(), x0[0].numpy(), x_obs[0].numpy(), int(steps),
                                          prior.numpy())
            return torch.from_numpy(raw_np)[None], torch.from_numpy(xs_np)[None]
        return fused_rollout(kernel, feature, x0, x_obs, int(steps), prior, fast["in"], fast["out"],
                             resolve_precision(precision, x0.device.type, x0.shape[0]))

    def rollout_arrays(self, feature: np.ndarray, vel0: np.ndarray, angvel0: np.ndarray, steps: int,
                       obs_vel: Optional[np.ndarray] = None, obs_angvel: Optional[np.ndarray] = None,
                       precision: str = "fp32") -> Tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """rollout_raw for numpy arrays, without autograd: the Predictor's entry point. A batch of one on the CPU
        never touches torch (the latency path: the prior's constants in float32 numpy, then numpy_rollout).

        Args:
            feature: (B, F) shape features.
            vel0, angvel0: (B, 3) the state at frame 0 in frame C.
            steps: steps to roll out.
            obs_vel, obs_angvel: optional (B, K, 3) observed states of frames 1..K (as rollout_raw).
            precision: of batches of more than one (rollout_raw); batch 1 runs the float32 numpy kernel.

        Returns:
            Raw outputs (B, steps, 13) and normalised inputs used (B, steps + 1, 6) as float32 arrays, and the
            scale vectors {"in": (6,), "out": (13,)} (float32) that make them physical.
        """
        with torch.inference_mode():
            fast = self._fast()
            if self.cfg.cell == "lstm":
                kernel = self._kernel(fast)
                if len(feature) == 1 and "np_w0" in kernel:  # (numpy weights exist for float32 CPU models)
                    scale_in = kernel["np_in"]
                    x0 = np.concatenate([vel0, angvel0], -1).astype(np.float32) / scale_in
                    if obs_vel is None:
                        x_obs = np.zeros((0, 6), np.float32)
                    else:
                        assert obs_angvel is not None, "obs_vel and obs_angvel go together"
                        x_obs = (np.concatenate([obs_vel[0], obs_angvel[0]], -1).astype(np.float32) / scale_in)[:steps]
                    prior = None
                    if self.cfg.prior != "none":  # _prior_decel in float32 numpy (torch's dispatch costs more)
                        radius = np.maximum(np.asarray(feature, np.float32)[:, self.learned_dim] * kernel["np_cloud"],
                                            np.float32(MIN_RADIUS))
                        decel = np.full_like(radius, float(self.cfg.prior_friction) * GRAVITY)
                        coupling = np.full_like(radius, float(self.cfg.prior == "coupled"))
                        prior = np.stack([decel, decel / radius, coupling], -1)
                    raw_np, xs_np = numpy_rollout(kernel, np.asarray(feature, np.float32), x0[0], x_obs, int(steps),
                                                  prior)
                    return raw_np[None], xs_np[None], {"in": scale_in, "out": kernel["np_out"]}
            device = fast["in"].device

            def tensor(a: Any) -> Any:  # None (no observed states) stays None
                return None if a is None else torch.from_numpy(np.array(a, np.float32)).to(device)

            raw, xs = self.rollout_raw(tensor(feature), tensor(vel0), tensor(angvel0), steps, tensor(obs_vel),
                                       tensor(obs_angvel), fast, precision)
            scales = {"in": fast["in"].float().cpu().numpy(), "out": fast["out"].float().cpu().numpy()}
            return raw.float().cpu().numpy(), xs.float().cpu().numpy(), scales

    def rollout(self, feature: Tensor, vel0: Tensor, angvel0: Tensor, steps: int,
                obs_vel: Optional[Tensor] = None, obs_angvel: Optional[Tensor] = None,
                precision: str = "fp32") -> dict[str, Tensor]:
        """Physical roll-out in frame C (rollout_raw, denormalised).

        Args:
            feature, vel0, angvel0, steps, obs_vel, obs_angvel, precision: as rollout_raw.

        Returns:
            "vel", "angvel" (B, steps + 1, 3): the states, frame 0 included; "d_vel", "d_angvel", "d_pos", "d_rot"
            (B, steps, 3): the per-step increments (d_rot a world-fixed axis-angle); "topple_logit" (B, steps).
        """
        fast = self._fast()
        raw, xs = self.rollout_raw(feature, vel0, angvel0, steps, obs_vel, obs_angvel, fast, precision)
        out = self.denormalize(raw, fast)
        x = xs * fast["in"]
        out["vel"], out["angvel"] = x[..., 0:3], x[..., 3:6]
        return out

    # ------------------------------------------------------------------------------------------- training
    def forward(self, cloud: Tensor, vel: Tensor, angvel: Tensor, feedback: bool = False) -> Tensor:
        """Training entry point (DDP wraps this): raw outputs (B, T-1, 13) for windows of T states.

        feedback=False: the paper's teacher forcing (ground-truth velocities at every step). feedback=True:
        only frame 0 is given and the model's own velocities are fed back, as at test time.
        """
        feature = self.encode(cloud)
        if not feedback:
            raw = self.teacher_forced(feature, vel[:, :-1], angvel[:, :-1])
        else:
            raw = self.rollout_raw(feature, vel[:, 0], angvel[:, 0], vel.shape[1] - 1)[0]
        # the centre-of-mass estimate (model.com_head) rides along as 3 extra columns of step 0, in cloud-scale
        # units (DDP needs every output a tensor): split them off with split_com()
        if self.com is None:
            return raw
        com = self.com(feature)
        return torch.cat([raw, torch.cat([com, com.new_zeros(com.shape[0], raw.shape[-1] - 3)], 1)[:, None]], 1)

    def split_com(self, out: Tensor) -> Tuple[Tensor, Optional[Tensor]]:
        """forward's output -> (raw outputs (B, T-1, 13), COM estimate (B, 3) in cloud-scale units or None)."""
        if self.com is None:
            return out, None
        return out[:, :-1], out[:, -1, :3]


def count_parameters(model: nn.Module) -> dict[str, int]:
    """Parameter counts per top-level part (for logs and the report)."""
    counts: dict[str, int] = {}
    for name, p in model.named_parameters():
        part = name.split(".")[0]
        counts[part] = counts.get(part, 0) + p.numel()
    counts["total"] = sum(counts.values())
    return counts
