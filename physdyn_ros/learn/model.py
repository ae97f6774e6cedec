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

import numpy as np
import torch
from torch import Tensor, nn

from ..conventions import GRAVITY
from .prior import MIN_RADIUS, prior_constants, prior_into, prior_raw
from .sections import known_keys
from .topple import ToppleHead

#: Per-step outputs: d_vel (0:3), d_angvel (3:6), d_pos (6:9), d_rot (9:12), topple logit (12).
OUT_DIM = 13
#: The normalisation scales, in buffer order. Each is one scalar per vector quantity (an RMS norm), so a
#: rotation about z commutes with normalisation and relative losses keep their geometric meaning.
STAT_KEYS = ("vel", "angvel", "d_vel", "d_angvel", "d_pos", "d_rot", "cloud")
CELLS = ("lstm", "mlp")
#: Rows per call of the fused inference kernel on the CPU: a block's gate buffers (4 x rows x 4 H floats) stay in
#: the L2 cache; larger batches run block after block.
KERNEL_ROWS = 256
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
    # learns large increments slowly: without it the first shipped model predicted 12.6 cm of travel for
    # 1.2-2 m/s pushes that slid 27.4 cm, even with the true velocities fed (bench/speed_bins.py). The paper has
    # no such path; model_paper.yaml keeps it off.
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


def _reorder_gates(w: Tensor) -> Tensor:
    """nn.LSTM gate blocks (i, f, g, o) -> (i, f, o, g): one sigmoid covers i, f, o in the roll-out kernel."""
    i, f, g, o = w.chunk(4, 0)
    return torch.cat([i, f, o, g], 0)


def _lstm_rollout(x0: Tensor, x_obs: Tensor, const0: Tensor, w_x: List[Tensor], w_h: List[Tensor],
                  bias: List[Tensor], w_out: Tensor, b_out: Tensor, w_skip: Tensor, gain: Tensor,
                  steps: int, prior: Tensor, scale_in: Tensor, scale_out: Tensor) -> Tuple[Tensor, Tensor]:
    """Closed-loop LSTM roll-out, compiled by TorchScript: ~25 tensor ops per step and no Python in the loop.

    The differentiable kernel (training with feedback, gradient-based planning: autograd on). Without autograd
    rollout_raw runs _fused_lstm_rollout or, at batch 1 on the CPU, _numpy_lstm_rollout (same function, faster).

    x0 (B, 6): normalised [v, w] at frame 0. x_obs (B, K, 6): observed inputs for frames 1..K ("steps in"),
    used instead of the model's own. const0 (B, 4H): layer-0 bias plus the (constant) shape-feature term.
    Weights are transposed with gates ordered (i, f, o, g). w_skip (6, 13) maps the step's input to the outputs
    (input_skip), or is empty (0, 13) without one. gain (6,): normalised output -> input increment.
    prior (B, 2): (mu g, mu g / r) of the sliding prior added to the outputs (learn/prior.py), or empty (0, 2);
    scale_in (6,), scale_out (13,): the normalisation the prior needs.
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
        if prior.shape[0] > 0:
            p = prior_raw(x, prior[:, 0], prior[:, 1], prior[:, 2], scale_in, scale_out)
            y = y + torch.cat([p, torch.zeros_like(p[:, :1])], 1)
        outs.append(y)
        if t < x_obs.shape[1]:
            x = x_obs[:, t]
        else:
            x = torch.addcmul(x, y[:, :6], gain)
        xs.append(x)
    return torch.stack(outs, 1), torch.stack(xs, 1)


def _fused_lstm_rollout(x0: Tensor, x_obs: Tensor, const0: Tensor, w: List[Tensor], b: List[Tensor], w_head: Tensor,
                        b_head: Tensor, gain: Tensor, steps: int, prior: Tensor, scale_in: Tensor,
                        scale_out: Tensor) -> Tuple[Tensor, Tensor]:
    """Inference roll-out (no autograd): the same function as _lstm_rollout in fewer, allocation-free operations.

    One matrix product per layer and step: a row buffer z = [x, h_0, ..., h_{L-1}] (B, 6 + L H) holds the step's
    input and every layer's hidden state, so layer 0 multiplies the view [x, h_0] and layer l the view
    [h_{l-1}, h_l] by one stacked weight matrix (w[l]: (6 + H or 2 H, 4 H)), the bias fused into addmm; the head
    (and input_skip) is one product of all of z with w_head (rows of the middle layers zero).
    Elementwise work uses only sigmoid (torch's tanh costs 3.4x its sigmoid per element on an AVX2 CPU): the g-gate
    columns of w, b and const0 are pre-scaled by 2, so tanh(a) = 2 sigmoid(2 a) - 1, and the cell state is kept
    as c' = -2 c, so that tanh(c) = 1 - 2 sigmoid(c'):
        s = sigmoid(g)                                  (i, f, o, g gates; one call, in place: one (rows, 4 H)
                                                         buffer in the L2 cache instead of two)
        c' <- s_f c' - 4 s_i s_g + 2 s_i                (= -2 (f c + i tanh(g)))
        h  = s_o - 2 s_o sigmoid(c')                    (= o tanh(c))
    17 operations per step for 2 layers (the TorchScript kernel above: ~25 plus as many slices), all writing into
    buffers made once. x_obs, const0, gain: as _lstm_rollout. Returns raw outputs (B, steps, 13) and the inputs
    used (B, steps + 1, 6).
    """
    batch = x0.shape[0]
    layers = len(w)
    hidden = w[layers - 1].shape[1] // 4
    dtype = x0.dtype
    z = torch.zeros(batch, 6 + layers * hidden, dtype=dtype, device=x0.device)
    z[:, :6] = x0
    x = z[:, :6]
    cs: List[Tensor] = []
    hs: List[Tensor] = []
    zin: List[Tensor] = []
    for layer in range(layers):
        cs.append(torch.zeros(batch, hidden, dtype=dtype, device=x0.device))
        lo = 6 + layer * hidden
        hs.append(z[:, lo:lo + hidden])
        zin.append(z[:, :6 + hidden] if layer == 0 else z[:, lo - hidden:lo + hidden])
    g = torch.empty(batch, 4 * hidden, dtype=dtype, device=x0.device)
    s = g  # the gates in place: one (rows, 4 H) buffer in the cache instead of two
    sc = torch.empty(batch, hidden, dtype=dtype, device=x0.device)
    s_i = s[:, :hidden]
    s_f = s[:, hidden:2 * hidden]
    s_o = s[:, 2 * hidden:3 * hidden]
    s_g = s[:, 3 * hidden:]
    ys = torch.empty(batch, steps, w_head.shape[1], dtype=dtype, device=x0.device)
    xs = torch.empty(batch, steps + 1, 6, dtype=dtype, device=x0.device)
    xs[:, 0] = x0
    observed = x_obs.shape[1]
    for t in range(steps):
        for layer in range(layers):
            if layer == 0:
                torch.addmm(const0, zin[0], w[0], out=g)
            else:
                torch.addmm(b[layer], zin[layer], w[layer], out=g)
            g.sigmoid_()
            c = cs[layer]
            c.mul_(s_f).addcmul_(s_i, s_g, value=-4.0).add_(s_i, alpha=2.0)
            torch.sigmoid(c, out=sc)
            torch.addcmul(s_o, s_o, sc, value=-2.0, out=hs[layer])
        y = ys[:, t]
        torch.addmm(b_head, z, w_head, out=y)
        if prior.shape[0] > 0:  # the sliding prior (model.prior), as in _lstm_rollout
            y[:, :12].add_(prior_raw(x, prior[:, 0], prior[:, 1], prior[:, 2], scale_in, scale_out))
        if t < observed:
            x.copy_(x_obs[:, t])
        else:
            x.addcmul_(y[:, :6], gain)
        xs[:, t + 1] = x
    return ys, xs


def _numpy_lstm_rollout(x0: np.ndarray, x_obs: np.ndarray, w0: np.ndarray, w: List[np.ndarray], w_head: np.ndarray,
                        steps: int, prior: Optional[tuple] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Batch-1 roll-out in numpy: the latency path (torch dispatch costs more than the arithmetic at batch 1, and
    its matrix-vector products are ~2x slower than numpy's BLAS on these sizes).

    x0 (6,), x_obs (K, 6) float32. Row vector z = [x, 1, h_0, 1, h_1, ...]: the 1 entries carry the biases inside
    the products. Only tanh is used (numpy has no sigmoid; sigmoid(a) = (1 + tanh(a / 2)) / 2): w0 (layer 0, rows
    [x, 1 (bias + shape-feature term), h_0]) and w[l] (rows [h_{l-1}, 1, h_l]) have gate columns (o, i, f, g),
    the o, i, f columns halved, and h rows halved because z stores 2 h = (1 + tanh(a_o / 2)) tanh(c).
    w_head (len(z), 19): columns the 13 outputs, then the next input x + gain * outputs[:6] (the feedback folded
    into the product). Returns raw outputs (steps, 13) and inputs used (steps + 1, 6), float32.
    """
    layers = len(w) + 1
    hidden = w0.shape[1] // 4
    z = np.zeros(7 + layers * (hidden + 1) - 1, np.float32)
    z[:6] = x0
    views = []
    for layer in range(layers):
        lo = 7 + layer * (hidden + 1)
        z[lo - 1] = 1.0
        inp = z[:lo + hidden] if layer == 0 else z[lo - hidden - 1:lo + hidden]
        q = np.zeros(5 * hidden, np.float32)  # tanh of the gates (o, i, f, g) then the cell state c
        prod = np.empty((2, hidden), np.float32)  # (2 i tanh(g), 2 f c)
        # per layer: product input, weights, gates, (o, i, f) view, (i, f), (g, c), products (2, H) and flat, c,
        # tanh(c), o, h slot
        views.append((inp, w0 if layer == 0 else w[layer - 1], q[:4 * hidden], q[:3 * hidden],
                      q[hidden:3 * hidden], q[3 * hidden:], prod, prod.reshape(-1), q[4 * hidden:],
                      np.empty(hidden, np.float32), q[:hidden], z[lo:lo + hidden]))
    out = np.empty((steps, OUT_DIM + 6), np.float32)
    rows = list(out)
    x = z[:6]
    one = np.float32(1.0)
    halves = np.full(2, 0.5, np.float32)
    dot, tanh, add, mul, copyto = np.dot, np.tanh, np.add, np.multiply, np.copyto
    observed = len(x_obs)
    for t in range(steps):  # 7 numpy calls per layer, outputs passed positionally (cheaper than out=)
        for inp, weights, t4, u3, u_if, g_c, prod, prod_flat, c, tc, u_o, h in views:
            dot(inp, weights, t4)
            tanh(t4, t4)
            add(u3, one, u3)  # 2 sigmoid(a) for o, i, f
            mul(u_if, g_c, prod_flat)  # (2 i tanh(g), 2 f c)
            dot(halves, prod, c)  # c <- (2 i tanh(g) + 2 f c) / 2: the sum and the halving (exact) in one call
            tanh(c, tc)
            mul(u_o, tc, h)  # 2 o tanh(c)
        row = rows[t]
        dot(z, w_head, row)
        if prior is not None:  # the sliding prior: on the outputs and, through the gain, on the next input
            prior_into(row, x, prior)
        if t < observed:
            row[OUT_DIM:] = x_obs[t]
        copyto(x, row[OUT_DIM:])
    xs = np.empty((steps + 1, 6), np.float32)
    xs[0] = x0
    xs[1:] = out[:, OUT_DIM:]
    return out[:, :OUT_DIM], xs


def _compile(fn: Any) -> Any:
    """TorchScript a roll-out kernel: it removes Python from the 60-step loop (~3x faster at batch 1) and, unlike
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
_fused_lstm_rollout = _compile(_fused_lstm_rollout)


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

    def _kernel(self, fast: dict[str, Any]) -> dict[str, Any]:
        """Weights of the inference kernels (_fused_lstm_rollout, _numpy_lstm_rollout), derived from `fast` once
        and kept in it: `fast` is the cached dict whenever autograd is off, so they are rebuilt only when a
        parameter changes. All rescalings are by powers of 2 (exact); only the numpy head's folded feedback
        (identity + gain * weights) rounds, by one float32 ulp."""
        kernel = fast.get("kernel")
        if kernel is None:
            with torch.inference_mode(False), torch.no_grad():
                kernel = self._build_kernel(fast)
            fast["kernel"] = kernel
        return kernel

    def _build_kernel(self, fast: dict[str, Any]) -> dict[str, Any]:
        hidden, layers = self.cfg.hidden_size, self.cfg.num_layers
        w_x, w_h, bias = fast["w_x"], fast["w_h"], fast["bias"]
        w_out, b_out, w_skip = fast["w_out"], fast["b_out"], fast["w_skip"]
        # torch kernel: gates (i, f, o, g), g columns doubled (tanh(a) = 2 sigmoid(2 a) - 1)
        two = torch.ones(4 * hidden, dtype=w_out.dtype, device=w_out.device)
        two[3 * hidden:] = 2.0
        w = [torch.cat([w_x[0][:6], w_h[0]], 0) * two] + [torch.cat([w_x[i], w_h[i]], 0) * two
                                                         for i in range(1, layers)]
        head = w_out.new_zeros(6 + layers * hidden, OUT_DIM)
        if w_skip.shape[0]:
            head[:6] = w_skip
        head[6 + (layers - 1) * hidden:] = w_out
        kernel: dict[str, Any] = {
            "w": [m.contiguous() for m in w], "b": [b * two for b in bias],
            "w_feature": (w_x[0][6:] * two).contiguous(), "head": head.contiguous(), "b_head": b_out.contiguous(),
            "gain": fast["gain"].contiguous()}
        if w_out.dtype != torch.float32 or w_out.device.type != "cpu":
            return kernel
        # numpy kernel (batch 1): gates (o, i, f, g), o/i/f columns halved (sigmoid(a) = (1 + tanh(a / 2)) / 2),
        # h rows halved (z holds 2 h), a bias row before each layer's own h rows: z = [x, 1, h_0, 1, h_1, ...]
        order = torch.cat([torch.arange(2 * hidden, 3 * hidden), torch.arange(0, 2 * hidden),
                           torch.arange(3 * hidden, 4 * hidden)])
        col = torch.ones(4 * hidden)
        col[:3 * hidden] = 0.5

        def gates(m: Tensor) -> np.ndarray:
            return np.ascontiguousarray((m[..., order] * col).numpy(), dtype=np.float32)

        w0 = gates(torch.cat([w_x[0][:6], torch.zeros(1, 4 * hidden), 0.5 * w_h[0]], 0))
        w_np = [gates(torch.cat([0.5 * w_x[i], bias[i][None], 0.5 * w_h[i]], 0)) for i in range(1, layers)]
        size = 6 + layers * (hidden + 1)
        last = 7 + (layers - 1) * (hidden + 1)
        head_np = torch.zeros(size, OUT_DIM + 6)
        if w_skip.shape[0]:
            head_np[:6, :OUT_DIM] = w_skip
        head_np[6, :OUT_DIM] = b_out
        head_np[last:last + hidden, :OUT_DIM] = 0.5 * w_out
        head_np[:, OUT_DIM:] = head_np[:, :6] * fast["gain"]
        head_np[:6, OUT_DIM:] += torch.eye(6)
        kernel.update(np_w0=w0, np_w=w_np, np_head=np.ascontiguousarray(head_np.numpy()),
                      np_w_feature=gates(w_x[0][6:]), np_b0=gates(bias[0]),
                      np_in=fast["in"].numpy().astype(np.float32), np_out=fast["out"].numpy().astype(np.float32),
                      np_gain=fast["gain"].numpy().astype(np.float32),
                      np_cloud=np.float32(self._scale("cloud").item()))
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
                    fast: Optional[dict[str, Any]] = None) -> tuple[Tensor, Tensor]:
        """Closed-loop roll-out: raw outputs (B, steps, 13) and normalised inputs used (B, steps + 1, 6).

        vel0/angvel0 (B, 3) are the state at frame 0; obs_vel/obs_angvel (B, K, 3) optionally observed states
        of frames 1..K, fed instead of the model's own predictions ("steps in" = K + 1).
        LSTM kernels: with autograd on the differentiable _lstm_rollout; without, the same function faster in
        _numpy_lstm_rollout (batch 1, float32 on the CPU) or _fused_lstm_rollout (test/test_rollout_kernels.py).
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
        if self.cfg.cell == "lstm":
            if torch.is_grad_enabled():  # training / gradients: the differentiable kernel
                w_x = fast["w_x"]
                const0 = torch.addmm(fast["bias"][0], feature, w_x[0][6:])  # the feature term is constant in time
                return _lstm_rollout(x0, x_obs, const0, [w_x[0][:6]] + w_x[1:], fast["w_h"], fast["bias"],
                                     fast["w_out"], fast["b_out"], fast["w_skip"], fast["gain"], int(steps),
                                     prior, fast["in"], fast["out"])
            kernel = self._kernel(fast)
            if x0.shape[0] == 1 and "np_w0" in kernel and x0.device.type == "cpu" and x0.dtype == torch.float32:
                raw_np, xs_np = self._numpy_kernel(kernel, feature.numpy(), x0[0].numpy(), x_obs[0].numpy(),
                                                   int(steps), prior.numpy())
                return torch.from_numpy(raw_np)[None], torch.from_numpy(xs_np)[None]
            return self._fused_kernel(kernel, feature, x0, x_obs, int(steps), prior, fast)
        x, outs, xs = x0, [], [x0]
        for t in range(steps):  # the MLP baseline is not latency critical
            y = self.mlp(torch.cat([x, feature], -1))
            if self.skip is not None:
                y = y + self.skip(x)
            if prior.shape[0] > 0:
                p = prior_raw(x, prior[:, 0], prior[:, 1], prior[:, 2], fast["in"], fast["out"])
                y = y + torch.cat([p, torch.zeros_like(p[:, :1])], 1)
            outs.append(y)
            x = x_obs[:, t] if t < x_obs.shape[1] else x + y[:, :6] * fast["gain"]
            xs.append(x)
        return torch.stack(outs, 1), torch.stack(xs, 1)

    @staticmethod
    def _numpy_kernel(kernel: dict[str, Any], feature: np.ndarray, x0: np.ndarray, x_obs: np.ndarray,
                      steps: int, prior: Optional[np.ndarray] = None) -> Tuple[np.ndarray, np.ndarray]:
        """Batch 1: feature (1, F), x0 (6,), x_obs (K, 6) float32 -> raw (steps, 13), inputs used (steps + 1, 6).
        prior: (1, 3) (mu g, spin deceleration, coupling) of the prior (_prior_decel), or None / empty."""
        w0 = kernel["np_w0"].copy()  # a private copy: the layer-0 bias row carries this object's feature term
        w0[6] = feature[0] @ kernel["np_w_feature"] + kernel["np_b0"]
        args = None
        if prior is not None and len(prior):
            args = prior_constants(prior[0, 0], prior[0, 1], kernel["np_in"], kernel["np_out"], kernel["np_gain"],
                                   coupling=float(prior[0, 2]))
        return _numpy_lstm_rollout(x0, x_obs, w0, kernel["np_w"], kernel["np_head"], steps, args)

    def _fused_kernel(self, kernel: dict[str, Any], feature: Tensor, x0: Tensor, x_obs: Tensor,
                      steps: int, prior: Optional[Tensor] = None,
                      fast: Optional[dict[str, Any]] = None) -> Tuple[Tensor, Tensor]:
        """_fused_lstm_rollout over blocks of KERNEL_ROWS rows (the block's gate buffers stay in the L2 cache)."""
        const0 = torch.addmm(kernel["b"][0], feature, kernel["w_feature"])
        rows = KERNEL_ROWS if x0.device.type == "cpu" else x0.shape[0]
        fast = fast or self._fast()
        prior = x0.new_zeros(0, 2) if prior is None else prior
        parts = [_fused_lstm_rollout(x0[i:i + rows], x_obs[i:i + rows], const0[i:i + rows], kernel["w"], kernel["b"],
                                     kernel["head"], kernel["b_head"], kernel["gain"], steps,
                                     prior[i:i + rows] if prior.shape[0] else prior, fast["in"], fast["out"])
                 for i in range(0, x0.shape[0], rows)]
        if len(parts) == 1:
            return parts[0]
        return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])

    def rollout_arrays(self, feature: np.ndarray, vel0: np.ndarray, angvel0: np.ndarray, steps: int,
                       obs_vel: Optional[np.ndarray] = None, obs_angvel: Optional[np.ndarray] = None
                       ) -> Tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """rollout_raw for numpy arrays, without autograd (the Predictor's entry point): raw outputs (B, steps, 13)
        and normalised inputs used (B, steps + 1, 6) as float32 arrays, plus the scale vectors "in" (6,) and
        "out" (13,) as float32. A batch of one on the CPU never touches torch (the latency path)."""
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
                    if self.cfg.prior != "none":  # _prior_decel in float32 numpy (torch: ~50 us of dispatch)
                        radius = np.maximum(np.asarray(feature, np.float32)[:, self.learned_dim] * kernel["np_cloud"],
                                            np.float32(MIN_RADIUS))
                        decel = np.full_like(radius, float(self.cfg.prior_friction) * GRAVITY)
                        coupling = np.full_like(radius, float(self.cfg.prior == "coupled"))
                        prior = np.stack([decel, decel / radius, coupling], -1)
                    raw_np, xs_np = self._numpy_kernel(kernel, np.asarray(feature, np.float32), x0[0], x_obs,
                                                       int(steps), prior)
                    return raw_np[None], xs_np[None], {"in": scale_in, "out": kernel["np_out"]}
            device = fast["in"].device

            def tensor(a: Any) -> Any:  # None (no observed states) stays None
                return None if a is None else torch.from_numpy(np.array(a, np.float32)).to(device)

            raw, xs = self.rollout_raw(tensor(feature), tensor(vel0), tensor(angvel0), steps, tensor(obs_vel),
                                       tensor(obs_angvel), fast)
            scales = {"in": fast["in"].float().cpu().numpy(), "out": fast["out"].float().cpu().numpy()}
            return raw.float().cpu().numpy(), xs.float().cpu().numpy(), scales

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
