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
"""`physdyn report BAG`: how well the recorded predictions matched what the object did.

For each push in the bag (bag/pushes.py), the prediction published for it (the first PredictedTrajectory stamped
within the push) is compared with the observed states at the prediction's last instant: final position error
(m, 3D and in the table plane), final rotation error (geodesic angle, deg) and toppling (predicted probability
> 0.5 vs observed tilt > 45 deg). When the observation stops before the predicted horizon, the last observed
pose is used if the object was at rest by then; otherwise the push is reported without errors.

A top-view PNG shows, per push, the observed centre-of-mass path (solid) and the predicted one (dashed).
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from .. import geometry as geo
from ..conventions import TOPPLE_ANGLE
from ..data.format import atomic_write
from .pushes import NS, Session, find_pushes, load_session, sample

MAX_PLOTS = 48


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", metavar="BAG", help="bag folder (or a single .mcap / .db3 file)")
    parser.add_argument("--png", help="top-view figure to write (default: <bag>_report.png next to the bag)")
    parser.add_argument("--json", help="also write the per-push numbers as JSON")
    parser.add_argument("--state-topic", help="object states (default: object_state, else odom, else object_pose)")
    parser.add_argument("--twist-topic", default="initial_twist", help="push starts ('' = detect motion onsets)")
    parser.add_argument("--prediction-topic", default="predicted_trajectory", help="PredictedTrajectory topic")
    parser.add_argument("--object-id", help="only states of this object_id / child_frame_id")


def evaluate(session: Session) -> list[dict]:
    """Per push: times, observed displacement, prediction errors (absent where not measurable).

    The object is taken to stay where it came to rest until the next push (a respawn or reset in between does
    not count as its motion).
    """
    rows = []
    st = session.states
    for push in find_pushes(session):
        row: dict = {"push": push.index, "t0": push.t0 / NS,
                     "rest_after": None if push.rest is None else (push.rest - push.t0) / NS}
        start, settled = sample(st, np.array([push.t0, push.settled]))["pos"]
        row["observed_displacement"] = float(np.linalg.norm(settled - start))
        settled = sample(st, np.array([push.settled]))["quat"]
        row["observed_toppled"] = bool(geo.up_tilt_angle(settled)[0] > TOPPLE_ANGLE)
        p = push.prediction
        row["predicted"] = p is not None
        if p is None:
            rows.append(row)
            continue
        t_final = p.t + int(round((len(p.pos) - 1) * p.dt * NS))
        row.update(model_id=p.model_id, steps_in=p.steps_in, horizon=len(p.pos) - 1,
                   horizon_s=(len(p.pos) - 1) * p.dt)
        if push.rest is not None:
            t_eval = min(t_final, push.rest)
        elif t_final <= push.end:
            t_eval = t_final
        else:
            row["note"] = "observation ends before the prediction's horizon while the object still moves"
            rows.append(row)
            continue
        obs = sample(st, np.array([t_eval]))
        err = p.pos[-1] - obs["pos"][0]
        row.update(position_error=float(np.linalg.norm(err)), planar_error=float(np.linalg.norm(err[:2])),
                   rotation_error_deg=float(np.degrees(geo.quat_angle_between(p.quat[-1], obs["quat"][0]))),
                   predicted_displacement=float(np.linalg.norm(p.pos[-1] - p.pos[0])),
                   predicted_toppled=bool(np.max(p.topple) > 0.5) if len(p.topple) else False)
        rows.append(row)
    return rows


def summarize(rows: list[dict]) -> dict:
    scored = [r for r in rows if "position_error" in r]
    out = {"pushes": len(rows), "with_prediction": sum(r["predicted"] for r in rows), "scored": len(scored)}
    if scored:
        pe = np.array([r["position_error"] for r in scored])
        re_ = np.array([r["rotation_error_deg"] for r in scored])
        agree = np.array([r["predicted_toppled"] == r["observed_toppled"] for r in scored])
        out.update(mean_position_error=float(pe.mean()), median_position_error=float(np.median(pe)),
                   mean_rotation_error_deg=float(re_.mean()), median_rotation_error_deg=float(np.median(re_)),
                   topple_accuracy=float(agree.mean()))
    return out


def plot(session: Session, rows: list[dict], path: Path) -> None:
    """Top view per push: observed path (solid), predicted path (dashed); written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pushes = {p.index: p for p in find_pushes(session)}
    shown = rows[:MAX_PLOTS]
    n = max(1, len(shown))
    cols = min(4, n)
    nrows = math.ceil(n / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(3.2 * cols, 3.2 * nrows), squeeze=False)
    st = session.states
    for ax, row in zip(axes.flat, shown):
        push = pushes[row["push"]]
        m = (st.t >= push.t0) & (st.t <= push.settled)
        ax.plot(st.pos[m, 0], st.pos[m, 1], "-", color="tab:blue", lw=1.5, label="observed")
        ax.plot(st.pos[m, 0][:1], st.pos[m, 1][:1], "o", color="black", ms=4)
        if push.prediction is not None:
            pp = push.prediction.pos
            ax.plot(pp[:, 0], pp[:, 1], "--", color="tab:orange", lw=1.5, label="predicted")
            ax.plot(pp[-1:, 0], pp[-1:, 1], "x", color="tab:orange", ms=6)
        if m.any():
            ax.plot(st.pos[m, 0][-1:], st.pos[m, 1][-1:], "s", color="tab:blue", ms=4)
        title = f"push {row['push']}"
        if "position_error" in row:
            title += f": {100 * row['position_error']:.1f} cm, {row['rotation_error_deg']:.0f} deg"
        ax.set_title(title, fontsize=9)
        ax.set_aspect("equal", adjustable="datalim")
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(shown):]:
        ax.axis("off")
    if not rows:
        axes.flat[0].text(0.5, 0.5, "no pushes in this bag", ha="center", va="center")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="upper right", fontsize=8)
    frame = session.frame_id or "table frame"
    more = f" (first {MAX_PLOTS} of {len(rows)})" if len(rows) > MAX_PLOTS else ""
    fig.suptitle(f"{session.bag.name}: top view, x / y in {frame} (m){more}", fontsize=10)
    fig.tight_layout()
    try:
        atomic_write(path, lambda fh: fig.savefig(fh, dpi=110, format="png"))
    finally:
        plt.close(fig)


def _fmt(v, scale: float = 1.0, digits: int = 1) -> str:
    return "-" if v is None else f"{v * scale:.{digits}f}"


def run(args: argparse.Namespace) -> int:
    session = load_session(args.bag, state_topic=args.state_topic, twist_topic=args.twist_topic or None,
                           prediction_topic=args.prediction_topic or None, cloud_topic=None,
                           object_id=args.object_id)
    rows = evaluate(session)
    summary = summarize(rows)
    print(f"{'push':>4} {'t0 (s)':>14} {'moved (cm)':>10} {'pred (cm)':>9} {'pos err (cm)':>12} "
          f"{'rot err (deg)':>13} {'toppled obs/pred':>16}  note")
    for r in rows:
        topple = f"{'yes' if r['observed_toppled'] else 'no'}/" + (
            ("yes" if r.get("predicted_toppled") else "no") if "predicted_toppled" in r else "-")
        note = r.get("note", "") if r["predicted"] else "no prediction recorded"
        if r["rest_after"] is None:
            note = (note + "; " if note else "") + "no rest observed"
        print(f"{r['push']:>4} {r['t0']:>14.3f} {_fmt(r['observed_displacement'], 100):>10} "
              f"{_fmt(r.get('predicted_displacement'), 100):>9} {_fmt(r.get('position_error'), 100, 2):>12} "
              f"{_fmt(r.get('rotation_error_deg')):>13} {topple:>16}  {note}")
    if summary["scored"]:
        print(f"{summary['scored']} push(es) scored: final position error mean "
              f"{100 * summary['mean_position_error']:.2f} cm (median {100 * summary['median_position_error']:.2f}), "
              f"rotation error mean {summary['mean_rotation_error_deg']:.1f} deg, topple agreement "
              f"{100 * summary['topple_accuracy']:.0f} %")
    else:
        print(f"{summary['pushes']} push(es), none with a recorded prediction to score")
    bag = Path(args.bag)
    base = bag.resolve()
    png = Path(args.png) if args.png else base.parent / f"{base.name if base.is_dir() else base.stem}_report.png"
    plot(session, rows, png)
    print(f"figure: {png}")
    if args.json:
        from ..data.format import write_json

        write_json(args.json, {"bag": str(bag.resolve()), "summary": summary, "pushes": rows})
    return 0
