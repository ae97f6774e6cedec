"""The dynamics network (Rempe et al. 2020), in one file.

    cloud (B, P, 3) in frame C --PointNet--> global feature --MLP--> shape feature f (B, F), once per object
    per step t:  [v_t, w_t, f] (6 + F) --LSTM (or the paper's memoryless MLP baseline)--> 13 numbers:
                 d_vel (3), d_angvel (3), d_pos (3), d_rot (3, world-fixed axis-angle in C), topple logit (1)
    roll-out:    v_{t+1} = v_t + d_vel_t and w_{t+1} = w_t + d_angvel_t are fed back as the next input.

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
from typing import Any, List, Optional, Tuple

import torch
from torch import Tensor, nn

from .sections import known_keys

#: Per-step outputs: d_vel (0:3), d_angvel (3:6), d_pos (6:9), d_rot (9:12), topple logit (12).
OUT_DIM = 13
#: The normalisation scales, in buffer order. Each is one scalar per vector quantity (an RMS norm), so a
#: rotation about z commutes with normalisation and relative losses keep their geometric meaning.
STAT_KEYS = ("vel", "angvel", "d_vel", "d_angvel", "d_pos", "d_rot", "cloud")
CELLS = ("lstm", "mlp")
NORMS = ("batch", "layer", "none")


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
    # learns large increments slowly: without it the first shipped model predicted 12.6 cm of travel for
    # 1.2-2 m/s pushes that slid 27.4 cm, even with the true velocities fed (bench/speed_bins.py). The paper has
    # no such path; model_paper.yaml keeps it off.
    input_skip: bool = False
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
        for key in ("num_points", "hidden_size", "num_layers", "mlp_layers", "max_horizon"):
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


def _reorder_gates(w: Tensor) -> Tensor:
    """nn.LSTM gate blocks (i, f, g, o) -> (i, f, o, g): one sigmoid covers i, f, o in the roll-out kernel."""
    i, f, g, o = w.chunk(4, 0)
    return torch.cat([i, f, o, g], 0)


def _lstm_rollout(x0: Tensor, x_obs: Tensor, const0: Tensor, w_x: List[Tensor], w_h: List[Tensor],
                  bias: List[Tensor], w_out: Tensor, b_out: Tensor, w_skip: Tensor, gain: Tensor,
                  steps: int) -> Tuple[Tensor, Tensor]:
    """Closed-loop LSTM roll-out, compiled by TorchScript: ~25 tensor ops per step and no Python in the loop.

    x0 (B, 6): normalised [v, w] at frame 0. x_obs (B, K, 6): observed inputs for frames 1..K ("steps in"),
    used instead of the model's own. const0 (B, 4H): layer-0 bias plus the (constant) shape-feature term.
    Weights are transposed with gates ordered (i, f, o, g). w_skip (6, 13) maps the step's input to the outputs
    (input_skip), or is empty (0, 13) without one. gain (6,): normalised output -> input increment.
    Returns raw outputs (B, steps, 13) and the inputs actually used (B, steps + 1, 6).
    """
    batch = x0.shape[0]
    hidden = w_h[0].shape[0]
    h3 = 3 * hidden
    hs = [torch.zeros(batch, hidden, dtype=x0.dtype, device=x0.device) for _ in range(len(w_h))]
    cs = [torch.zeros(batch, hidden, dtype=x0.dtype, device=x0.device) for _ in range(len(w_h))]
    x = x0
    outs: List[Tensor] = []
    xs: List[Tensor] = [x0]
    for t in range(steps):
        inp = x
        for layer in range(len(w_h)):
            if layer == 0:
                g = torch.addmm(torch.addmm(const0, inp, w_x[0]), hs[0], w_h[0])
            else:
                g = torch.addmm(torch.addmm(bias[layer], inp, w_x[layer]), hs[layer], w_h[layer])
            s = torch.sigmoid(g[:, :h3])
            c = torch.addcmul(s[:, hidden:2 * hidden] * cs[layer], s[:, :hidden], torch.tanh(g[:, h3:]))
            cs[layer] = c
            hs[layer] = s[:, 2 * hidden:h3] * torch.tanh(c)
            inp = hs[layer]
        y = torch.addmm(b_out, inp, w_out)
        if w_skip.shape[0] > 0:
            y = torch.addmm(y, x, w_skip)
        outs.append(y)
        if t < x_obs.shape[1]:
            x = x_obs[:, t]
        else:
            x = torch.addcmul(x, y[:, :6], gain)
        xs.append(x)
    return torch.stack(outs, 1), torch.stack(xs, 1)


def _compile(fn: Any) -> Any:
    """TorchScript the roll-out kernel: it removes Python from the 60-step loop (~3x faster at batch 1) and, unlike
    torch.compile, needs no C++ toolchain or long compilation at load. torch marks TorchScript deprecated; if a
    future torch drops it, the same function runs eagerly (slower, identical results)."""
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            return torch.jit.script(fn)
    except Exception:  # noqa: BLE001 - any scripting failure: run eagerly
        return fn


_lstm_rollout = _compile(_lstm_rollout)


class DynamicsModel(nn.Module):
    """Shape encoder + state predictor. See the module docstring for the data flow."""

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
        self.feature_dim = cfg.shape_mlp[-1]
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

    def set_normalization(self, stats: dict[str, float]) -> None:
        missing = [k for k in STAT_KEYS if k not in stats]
        if missing:
            raise ValueError(f"normalization stats lack {missing}")
        values = torch.tensor([float(stats[k]) for k in STAT_KEYS])
        if not torch.all(torch.isfinite(values)) or torch.any(values <= 0):
            raise ValueError(f"normalization scales must be finite and positive: {dict(zip(STAT_KEYS, values.tolist()))}")
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
                self._cache_params = list(self.parameters()) + [self.scales]
            key = tuple((p.data_ptr(), p._version) for p in self._cache_params)
            if self._cache is not None and self._cache_key == key:
                return self._cache
        if torch.is_grad_enabled():
            return self._build_fast()
        with torch.inference_mode(False), torch.no_grad():  # normal tensors: usable in and out of inference mode
            self._cache, self._cache_key = self._build_fast(), key
        return self._cache

    def _build_fast(self) -> dict[str, Any]:
        fast: dict[str, Any] = self._scale_vectors()
        if self.cfg.cell == "lstm":
            w_x: list[Tensor] = []
            w_h: list[Tensor] = []
            bias: list[Tensor] = []
            for layer in range(self.cfg.num_layers):
                w_x.append(_reorder_gates(getattr(self.lstm, f"weight_ih_l{layer}")).t().contiguous())
                w_h.append(_reorder_gates(getattr(self.lstm, f"weight_hh_l{layer}")).t().contiguous())
                bias.append(_reorder_gates(getattr(self.lstm, f"bias_ih_l{layer}")
                                           + getattr(self.lstm, f"bias_hh_l{layer}")))
            w_skip = (self.skip.weight.t().contiguous() if self.skip is not None
                      else self.head.weight.new_zeros(0, OUT_DIM))
            fast.update(w_x=w_x, w_h=w_h, bias=bias, w_out=self.head.weight.t().contiguous(), b_out=self.head.bias,
                        w_skip=w_skip)
        return fast

    # --------------------------------------------------------------------------------------------- pieces
    def encode(self, cloud: Tensor) -> Tensor:
        """Shape feature (B, F) of clouds (B, P, 3) in frame C, metres, centred at their centroid."""
        x = self.pointnet(cloud / self._scale("cloud"))
        return self.shape_mlp(x.max(dim=1).values)

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
        x = self._inputs(vel, angvel)
        x = torch.cat([x, feature[:, None, :].expand(-1, x.shape[1], -1)], -1)
        y = self.head(self.lstm(x)[0]) if self.cfg.cell == "lstm" else self.mlp(x)
        return y if self.skip is None else y + self.skip(x[..., :6])

    def rollout_raw(self, feature: Tensor, vel0: Tensor, angvel0: Tensor, steps: int,
                    obs_vel: Optional[Tensor] = None, obs_angvel: Optional[Tensor] = None,
                    fast: Optional[dict[str, Any]] = None) -> tuple[Tensor, Tensor]:
        """Closed-loop roll-out: raw outputs (B, steps, 13) and normalised inputs used (B, steps + 1, 6).

        vel0/angvel0 (B, 3) are the state at frame 0; obs_vel/obs_angvel (B, K, 3) optionally observed states
        of frames 1..K, fed instead of the model's own predictions ("steps in" = K + 1).
        """
        fast = fast or self._fast()
        x0 = self._inputs(vel0, angvel0, fast)
        if obs_vel is None:
            x_obs = x0.new_zeros(x0.shape[0], 0, 6)
        else:
            x_obs = self._inputs(obs_vel, obs_angvel, fast)[:, :steps]
        if self.cfg.cell == "lstm":
            w_x = fast["w_x"]
            const0 = torch.addmm(fast["bias"][0], feature, w_x[0][6:])  # the feature term is constant in time
            return _lstm_rollout(x0, x_obs, const0, [w_x[0][:6]] + w_x[1:], fast["w_h"], fast["bias"],
                                 fast["w_out"], fast["b_out"], fast["w_skip"], fast["gain"], int(steps))
        x, outs, xs = x0, [], [x0]
        for t in range(steps):  # the MLP baseline is not latency critical
            y = self.mlp(torch.cat([x, feature], -1))
            if self.skip is not None:
                y = y + self.skip(x)
            outs.append(y)
            x = x_obs[:, t] if t < x_obs.shape[1] else x + y[:, :6] * fast["gain"]
            xs.append(x)
        return torch.stack(outs, 1), torch.stack(xs, 1)

    def rollout(self, feature: Tensor, vel0: Tensor, angvel0: Tensor, steps: int,
                obs_vel: Optional[Tensor] = None, obs_angvel: Optional[Tensor] = None) -> dict[str, Tensor]:
        """Physical roll-out in C: vel/angvel (B, steps+1, 3), d_pos/d_rot (B, steps, 3), topple_logit (B, steps)."""
        fast = self._fast()
        raw, xs = self.rollout_raw(feature, vel0, angvel0, steps, obs_vel, obs_angvel, fast)
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
            return self.teacher_forced(feature, vel[:, :-1], angvel[:, :-1])
        return self.rollout_raw(feature, vel[:, 0], angvel[:, 0], vel.shape[1] - 1)[0]


def count_parameters(model: nn.Module) -> dict[str, int]:
    """Parameter counts per top-level part (for logs and the report)."""
    counts: dict[str, int] = {}
    for name, p in model.named_parameters():
        part = name.split(".")[0]
        counts[part] = counts.get(part, 0) + p.numel()
    counts["total"] = sum(counts.values())
    return counts
