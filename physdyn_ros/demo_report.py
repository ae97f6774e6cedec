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
"""What a push of `physdyn demo` yields, how it is judged, and the picture of them all (demo.png).

PushResult is one push as results.json stores it; `verdict` and `summary` judge it; `plot` draws every push of
every table (matplotlib, Agg: no display needed). Nothing here talks to ROS: a results.json of an earlier run can
be drawn again:

    data = json.loads(Path("runs/demo/results.json").read_text())
    plot([PushResult(**p) for p in data["pushes"]], Path("demo.png"), data["model_id"])
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:  # matplotlib itself is imported by plot, after choosing its backend
    from matplotlib.axes import Axes

__all__ = ["VERDICTS", "PushResult", "footprint", "heading", "nice_length", "plot", "summary", "verdict"]

#: (verdict, position cm, rotation deg): the first whose bounds hold, with the topple predicted right.
VERDICTS = (("GOOD", 2.0, 10.0), ("FAIR", 5.0, 30.0))


@dataclass
class PushResult:
    index: int
    shape: str
    category: str
    table: int  # 1, 2, ...: which table (set of objects) the object was on
    object_id: str  # the sim's id, pushed by it
    tracked_id: str  # the perception node's id, the predictor was asked by it
    tracked_id_after: str  # the tracked id of the object where it came to rest ("" if none within MATCH_DISTANCE)
    impulse: list[float]
    initial_lin_vel: list[float]
    initial_ang_vel: list[float]
    predicted_final: list[float]  # x, y, z at the scored step
    true_final: list[float]
    position_error_cm: float  # at the scored step: the last, or the last upright one of a push that toppled
    rotation_error_deg: float
    mean_position_error_cm: float  # over steps 0..scored
    scored_step: int
    topple_probability: float
    predicted_topple: bool
    toppled: bool
    true_topple_step: int  # first step tilted over 45 deg; -1 when it stayed upright
    verdict: str
    predicted_xy: list[list[float]]
    true_xy: list[list[float]]
    predicted_quat: list[float]  # x, y, z, w at the scored step
    true_quat: list[float]
    start_quat: list[float]
    outline: list[list[float]]  # surface points in the object frame (centre of mass, body axes), m


def verdict(position_cm: float, rotation_deg: float, topple_right: bool) -> str:
    for name, cm, deg in VERDICTS:
        if topple_right and position_cm <= cm and rotation_deg <= deg:
            return name
    return "POOR"


def summary(results: list[PushResult]) -> str:
    good = sum(r.verdict == "GOOD" for r in results)
    fair = sum(r.verdict == "FAIR" for r in results)
    right = sum(r.predicted_topple == r.toppled for r in results)
    return (f"{good} of {len(results)} pushes GOOD (within 2 cm and 10 deg), {fair} FAIR (5 cm, 30 deg); "
            f"topple predicted right in {right} of {len(results)}")


def nice_length(span_cm: float) -> float:
    """A round scale-bar length (1, 2 or 5 times a power of ten cm) about a quarter of `span_cm`."""
    target = max(span_cm / 4.0, 1e-3)
    base = 10.0 ** math.floor(math.log10(target))
    return max(m * base for m in (1.0, 2.0, 5.0) if m * base <= target)


def footprint(outline_body: np.ndarray, position: ArrayLike, quat: ArrayLike) -> np.ndarray:
    """Closed 2-D convex outline (cm) of the object's points posed at (position, quat), seen from above."""
    from scipy.spatial import ConvexHull
    from scipy.spatial.transform import Rotation

    xy = (Rotation.from_quat(quat).apply(outline_body) + np.asarray(position))[:, :2] * 100.0
    try:
        hull = xy[ConvexHull(xy).vertices]
    except Exception:  # noqa: BLE001 - a degenerate outline (a line seen from above) is drawn as its points
        hull = xy
    return np.vstack([hull, hull[:1]])


def heading(outline_body: np.ndarray, position: ArrayLike, quat: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Arrow (start, delta) in cm along the object's body x axis, as long as the object's reach."""
    from scipy.spatial.transform import Rotation

    reach = float(np.linalg.norm(outline_body[:, :2], axis=1).max()) if len(outline_body) else 0.05
    d = Rotation.from_quat(quat).apply([1.0, 0.0, 0.0])[:2]
    return np.asarray(position)[:2] * 100.0, d / max(np.linalg.norm(d), 1e-9) * reach * 100.0


def plot(results: list[PushResult], path: Path, model_id: str) -> None:
    """One row per table: the table from above with every object's start outline and its true (solid) and
    predicted (dashed) path and final pose in its own colour; then one top view per push, every push panel at ONE
    scale: outlines and headings at the start (grey), the true (black) and the predicted (red, dashed) pose at the
    scored step; the true path after a topple is dotted and not scored."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    colours = {"GOOD": "tab:green", "FAIR": "tab:orange", "POOR": "tab:red"}
    panels = []
    for r in results:
        t, p = 100 * np.array(r.true_xy), 100 * np.array(r.predicted_xy)
        body = np.array(r.outline).reshape(-1, 3)
        k = r.scored_step
        shapes = {"start": footprint(body, r.true_xy[0] + [0.0], r.start_quat),
                  "true": footprint(body, r.true_final, r.true_quat),
                  "pred": footprint(body, r.predicted_final, r.predicted_quat)}
        scored = np.vstack([t[: k + 1], p[: k + 1]] + list(shapes.values()))
        panels.append((r, t, p, body, shapes, scored))
    # one scale for every push panel: the largest scored extent decides
    half = 0.55 * max(float(np.ptp(sc, axis=0).max()) for *_, sc in panels) + 1.0
    bar = nice_length(2 * half)
    tables = sorted({r.table for r in results})
    cols = 1 + max(sum(r.table == tb for r in results) for tb in tables)
    fig, axes = plt.subplots(len(tables), cols, figsize=(4.3 * cols, 5.0 * len(tables)), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for row, tb in enumerate(tables):
        mine = [pn for pn in panels if pn[0].table == tb]
        table_panel(axes[row, 0], tb, mine)
        for (r, t, p, body, shapes, scored), ax in zip(mine, axes[row, 1:]):
            ax.axis("on")
            push_panel(ax, r, t, p, body, shapes, scored, half, bar, colours[r.verdict])
    handles = {}
    for ax in axes[:, 1:].flat:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    handles["heading (body x axis)"] = Line2D([], [], color="k", marker=">", lw=1.0, markevery=[1])
    handles["path of the centre of mass"] = Line2D([], [], color="k", lw=1.0)
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=min(7, len(handles)), fontsize=8,
               frameon=False)
    fig.suptitle(f"physdyn demo, model {model_id}: top views, {len(results[0].true_xy) - 1} steps of 1/15 s; left: "
                 "each table, right: each push (at one scale)\n" + summary(results), fontsize=10)
    fig.tight_layout(rect=(0, 0.04, 1, 0.96), h_pad=4.0)  # room for the three-line titles of the next row
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table_panel(ax: Axes, table: int, panels: list[tuple[Any, ...]]) -> None:
    """The whole table: each object's start outline, true path and outline at the scored step (solid) and
    predicted ones (dashed) in the object's colour, labelled with its sim id and tracked id."""
    ax.axis("on")
    cmap = ["tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink"]
    everything = []
    for j, (r, t, p, body, shapes, scored) in enumerate(panels):
        colour = cmap[j % len(cmap)]
        t, p = t[: r.scored_step + 1], p[: r.scored_step + 1]  # a toppled object's roll is not scored
        ax.fill(*shapes["start"].T, color=colour, alpha=0.18, zorder=1)
        ax.plot(*t.T, "-", color=colour, lw=1.4, zorder=3)
        ax.plot(*p.T, "--", color=colour, lw=1.4, zorder=4)
        ax.plot(*shapes["true"].T, "-", color=colour, lw=1.0, zorder=3)
        ax.plot(*shapes["pred"].T, "--", color=colour, lw=1.0, zorder=4)
        c0 = shapes["start"][:-1].mean(axis=0)
        ax.text(c0[0], c0[1], f"{r.object_id}\n{r.tracked_id}", ha="center", va="center", fontsize=7, zorder=6)
        everything += [t, p] + list(shapes.values())
    pts = np.vstack(everything)
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    half = 0.55 * float(np.ptp(pts, axis=0).max()) + 2.0
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    bar = nice_length(2 * half)
    x0, y0 = centre[0] - 0.9 * half, centre[1] - 0.88 * half
    ax.plot([x0, x0 + bar], [y0, y0], "-", color="k", lw=3, solid_capstyle="butt")
    ax.text(x0 + bar / 2, y0 + 0.04 * half, f"{bar:g} cm", ha="center", va="bottom", fontsize=8)
    ax.set_title(f"table {table}: {len(panels)} objects (sim id / tracked id)\ntrue path solid, predicted dashed",
                 fontsize=8.5)


def push_panel(ax: Axes, r: PushResult, t: np.ndarray, p: np.ndarray, body: np.ndarray, shapes: dict,
               scored: np.ndarray, half: float, bar: float, colour: str) -> None:
    """One push from above (see plot)."""
    k = r.scored_step
    centre = 0.5 * (scored.min(axis=0) + scored.max(axis=0))
    ax.fill(*shapes["start"].T, color="0.85", zorder=1, label="start")
    ax.plot(*shapes["true"].T, "-", color="k", lw=1.6, zorder=3, label="true pose")
    ax.plot(*shapes["pred"].T, "--", color="tab:red", lw=1.6, zorder=4, label="predicted pose")
    for (pos, q), c in (((r.true_xy[0] + [0.0], r.start_quat), "0.45"), ((r.true_final, r.true_quat), "k"),
                        ((r.predicted_final, r.predicted_quat), "tab:red")):
        start, delta = heading(body, pos, q)
        ax.annotate("", start + delta, start, arrowprops=dict(arrowstyle="->", color=c, lw=1.3), zorder=5)
    ax.plot(*t[: k + 1].T, "-", color="k", lw=1.0, zorder=3)
    ax.plot(*p[: k + 1].T, "--", color="tab:red", lw=1.0, zorder=4)
    if r.toppled:
        ax.plot(*t[k:].T, ":", color="0.4", lw=1.0, zorder=2, label="after the topple (not scored)")
        ax.plot(*t[r.true_topple_step], "x", color="k", ms=9, mew=2, zorder=6, label="true topple")
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    x0, y0 = centre[0] - 0.9 * half, centre[1] - 0.88 * half
    ax.plot([x0, x0 + bar], [y0, y0], "-", color="k", lw=3, solid_capstyle="butt")
    ax.text(x0 + bar / 2, y0 + 0.04 * half, f"{bar:g} cm", ha="center", va="bottom", fontsize=8)
    when = f"at {k / 15:.1f} s, the last upright frame" if r.toppled else f"at {k / 15:.1f} s (the end)"
    topple = (f"topple: predicted {'yes' if r.predicted_topple else 'no'} (p {r.topple_probability:.2f}), "
              f"true {'yes' if r.toppled else 'no'}")
    ax.set_title(f"{r.index}: {r.object_id} ({r.tracked_id}) {r.shape}   {r.verdict}\nerror "
                 f"{r.position_error_cm:.1f} cm, {r.rotation_error_deg:.0f} deg {when}\n{topple}", fontsize=8,
                 color=colour)
