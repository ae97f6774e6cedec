"""Optional gradient refinement of the best CEM push, by backpropagation through the learned model (torch).

Only for a physdyn_ros.predictor.Predictor (other DynamicsModels have no gradients: the refinement is skipped).
The final pose is rebuilt differentiably from the model's increments in its canonical frame C:
    final xy = start xy + R(heading) sum_t d_pos_t        final yaw = start yaw + sum_t d_rot_t . z
(the yaw sum is exact for rotations about z, i.e. for the upright pushes the planner accepts). The push's
velocity (vx, vy) is optimised with Adam on the planner's cost (without the hard limits), at the contact point
CEM chose (w = (I/m)^-1 (r x v) with r fixed); the result is re-scored with the ordinary batched roll-out
(which finds the contact again on the surface) and kept only if it is better, so refinement never hurts.
"""
from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any, Optional

import numpy as np

from .planner import MOVING_SCALE

if TYPE_CHECKING:
    from .planner import _Candidate, _Search


def torch_model(model: Any) -> Optional[Any]:
    """The torch DynamicsModel behind a Predictor (public `torch_model` if the Predictor offers it), else None."""
    for name in ("torch_model", "module", "_model"):
        m = getattr(model, name, None)
        if m is not None and hasattr(m, "rollout") and hasattr(m, "parameters"):
            return m
    return None


def refine_candidate(search: "_Search", best: "_Candidate") -> "_Candidate":
    net = torch_model(search.model)
    code = search.code
    if net is None or not hasattr(code, "feature") or not hasattr(code, "heading"):
        return best
    import torch

    cfg, goal, start, body = search.cfg, search.goal, search.start, search.body
    dev = next(net.parameters()).device
    f32 = dict(dtype=torch.float32, device=dev)
    # the dynamics network reads its own part of the code (a topple head appends support descriptors)
    feature = torch.as_tensor(np.asarray(code.feature, dtype=np.float32)[:net.feature_dim], **f32)[None]
    h = float(code.heading)
    rot_c2w = torch.tensor([[math.cos(h), -math.sin(h)], [math.sin(h), math.cos(h)]], **f32)
    inv_inertia = torch.as_tensor(np.linalg.inv(body.inertia_per_mass), **f32)
    lever = torch.as_tensor(best.contact - body.com, **f32)
    goal_xy = torch.as_tensor(goal.pose.xy, **f32)
    start_xy = torch.as_tensor(start.xy, **f32)
    scale = torch.tensor([cfg.max_speed, cfg.max_speed], **f32)
    x = torch.tensor([best.speed * best.direction[0], best.speed * best.direction[1]], **f32)
    x = (x / scale).clone().requires_grad_(True)
    opt = torch.optim.Adam([x], lr=cfg.refine_lr)
    t_step: Optional[float] = None
    params = []
    for _ in range(cfg.refine_steps):
        t = time.perf_counter()
        if t_step is not None and t + t_step > search.deadline:
            break
        with torch.enable_grad():
            p = x * scale
            v = p[:2]
            s = torch.linalg.norm(v).clamp_min(1e-6)
            d = v / s
            s = s.clamp(cfg.min_speed, cfg.max_speed)
            vel = torch.cat([s * d, v.new_zeros(1)])
            w = inv_inertia @ torch.linalg.cross(lever, vel)
            # world -> C: rotate by -heading about z
            vel_c = torch.cat([rot_c2w.T @ vel[:2], vel[2:]])
            w_c = torch.cat([rot_c2w.T @ w[:2], w[2:]])
            out = net.rollout(feature, vel_c[None], w_c[None], search.horizon)
            final_xy = start_xy + rot_c2w @ out["d_pos"][0, :, :2].sum(0)
            dyaw = out["d_rot"][0, :, 2].sum()
            pos_err = torch.linalg.norm(final_xy - goal_xy)
            cost = (pos_err / goal.position_tolerance) ** 2
            cost = cost + (torch.linalg.norm(out["vel"][0, -1]) / MOVING_SCALE) ** 2
            cost = cost + 2.0 * torch.sigmoid(out["topple_logit"][0]).max()
            if not goal.ignores_yaw:
                err = torch.remainder(start.yaw + dyaw - goal.pose.yaw + math.pi, 2 * math.pi) - math.pi
                cost = cost + (err / goal.yaw_tolerance) ** 2
            # grad w.r.t. the push only: the model's weights get no .grad (the Predictor is shared)
            (x.grad,) = torch.autograd.grad(cost, [x])
            opt.step()
        vxy = (x.detach() * scale).cpu().numpy().astype(np.float64)
        params.append(np.array([vxy[0], vxy[1], best.fraction, best.height_fraction]))
        t_step = time.perf_counter() - t
    if not params:
        return best
    # re-score the last few iterates with the planner's own (batched, exact) evaluation
    cands = search.evaluate(np.array(params[-4:]))
    winner = min(cands, key=lambda c: c.cost)
    if winner.cost >= best.cost:
        return best
    cfg = search.cfg
    if search.checked:  # the refined push passes the robustness check the CEM's winner passed, or is not taken
        search._perturb([winner], cfg.robust_samples)
        if winner.robust_topple > cfg.max_topple_probability:
            return best
    return winner
