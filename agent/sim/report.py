"""Run reports: ``result.json`` and PNG plots of a :class:`~agent.sim.result.SimResult`.

``result.json`` (msgspec-encoded; units m, s, rad; infinite bounds are ``null``)::

    scenario, seed, planar, d_opt         name, seed, 2-D mode, optimal distance [m]
    agents                                agent ids, in scenario order
    landmark_ids                          landmark ids, in row order of q
    landmarks                             [{id, position, normal}]
    space                                 {lo: [x|null, y|null, z|null], hi: [...]}
    duration                              last simulated time [s]
    initial_poses, final_poses            {agent: {position: [x, y, z], direction: [x, y, z]}}
    initial_partition, final_partition    {agent: [landmark ids]}
    coverage                              [[t, coverage score (eq. 3.10)], ...]
    visibility                            the scenario's model: "facing" or "occlusion"
    coverage_by_model                     structure runs: {facing: [[t, c], ...], occlusion:
                                           [[t, c], ...]} (coverage under each model); else null
    vision                                {agent: [[t, vision of own set], ...]}
    trades                                [{t, initiator, partner, to_partner, to_initiator,
                                            gain}]
    complete, t_complete                  mission complete, and when [s] (or null)
    checks                                {all_visible_to_owner, not_visible (ids; at completion),
                                           min_pairwise_distance [m] (null: one agent),
                                           stayed_inside_space, max_outside_space [m]}
    captures, inspection                  inspection missions (agent.sim.inspection_report)
    time_axis                             {scale [mission s / wall s], wall_origin [s since
                                           the epoch] or null (a simulation), clock_offsets
                                           {agent: s}}: every t above is mission time τ; a
                                           wall time w is τ = scale·(w − wall_origin), an
                                           agent's clock t is τ = t − clock_offsets[agent]
    missing                               only in the report of a recording without agent
                                           states: what it lacks (coverage, vision, trades
                                           empty, final_partition null)

Plots (Agg canvas, never a display): ``trajectories.png`` (2-D: paths over the vision map of
agent 0's initial set; 3-D: paths and landmarks), ``coverage.png`` (coverage and per-agent
vision over time, trades marked), ``partition.png`` (final partition and camera poses).

Inspection missions also get ``captures.png`` (landmarks by best capture quality).

(Just over 400 lines, not split: the document and the plots read the same result helpers.)
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec
import numpy as np
from numpy.typing import NDArray

from agent.core.orientation import optimal_orientation
from agent.core.vision import as_distance_term, vision
from agent.sim.inspection_report import inspection_document, plot_captures
from agent.sim.landmark_report import metric_axes_3d
from agent.sim.result import SimResult

if TYPE_CHECKING:  # matplotlib loads only when a plot is drawn (~0.4 s at start-up)
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

Array = NDArray[np.float64]

__all__ = ["RESULT_KEYS", "result_document", "vision_map", "write_report"]

#: Top-level keys of ``result.json``.
RESULT_KEYS: tuple[str, ...] = (
    "scenario", "seed", "planar", "d_opt", "agents", "landmark_ids", "landmarks", "space",
    "duration", "initial_poses", "final_poses", "initial_partition", "final_partition",
    "coverage", "visibility", "coverage_by_model", "vision", "trades", "complete", "t_complete",
    "checks", "captures", "inspection", "time_axis",
)
#: Largest landmark set for which the 2-D vision map uses Algorithm 1 at every grid point
#: (:func:`agent.core.orientation.optimal_orientation`); larger sets sample directions.
EXACT_MAP_MAX_LANDMARKS = 6
#: Tolerance [m] when checking that the agents stayed inside the mission space.
SPACE_TOL = 1e-6
#: Largest landmark set whose ids are written next to the landmarks in 3-D plots.
LABEL_MAX_LANDMARKS = 60


def _num(x: float) -> float | None:
    """A JSON-safe float (non-finite → null)."""
    x = float(x)
    return x if np.isfinite(x) else None


def _vec(a: Array) -> list[float | None]:
    return [_num(x) for x in np.asarray(a, dtype=np.float64).reshape(-1)]


def _partition(result: SimResult, owner: NDArray[np.intp]) -> dict[str, list[int]]:
    ids = np.asarray(result.landmark_ids)
    return {aid: ids[owner == i].tolist() for i, aid in enumerate(result.agent_ids)}


def _poses(result: SimResult, k: int) -> dict[str, dict[str, list[float | None]]]:
    return {
        aid: {"position": _vec(result.positions[k, i]), "direction": _vec(result.directions[k, i])}
        for i, aid in enumerate(result.agent_ids)
    }


def _checks(result: SimResult) -> dict[str, Any]:
    """End-of-run checks: ownership visibility (at completion: a recorded flight goes on home
    and lands), separation and mission-space containment (over the whole run)."""
    owner = result.final_owner
    k = result.completion_index()
    p = result.positions[k][owner]  # (m, 3) pose of each landmark's owner
    v = result.directions[k][owner]
    d = result.q - p
    seen = (np.einsum("ij,ij->i", d, v) > 0.0) & (np.einsum("ij,ij->i", d, result.u) < 0.0)
    not_visible = np.asarray(result.landmark_ids)[~seen].tolist()
    n = result.positions.shape[1]
    min_dist: float | None = None
    if n > 1:
        pos = result.positions
        diff = pos[:, :, None, :] - pos[:, None, :, :]  # (T, n, n, 3)
        dist = np.linalg.norm(diff, axis=-1)
        iu = np.triu_indices(n, k=1)
        min_dist = float(dist[:, iu[0], iu[1]].min())
    below = np.maximum(result.space_lo - result.positions, 0.0)
    above = np.maximum(result.positions - result.space_hi, 0.0)
    outside = float(np.max(np.maximum(below, above), initial=0.0))
    return {
        "all_visible_to_owner": not not_visible,
        "not_visible": not_visible,
        "min_pairwise_distance": min_dist,
        "stayed_inside_space": outside <= SPACE_TOL,
        "max_outside_space": outside,
    }


def result_document(result: SimResult) -> dict[str, Any]:
    """The content of ``result.json`` as plain Python data (see the module docstring)."""
    t = result.times
    return {
        "scenario": result.scenario,
        "seed": int(result.seed),
        "planar": bool(result.planar),
        "d_opt": float(result.d_opt),
        "agents": list(result.agent_ids),
        "landmark_ids": [int(x) for x in result.landmark_ids],
        "landmarks": [
            {"id": int(lid), "position": _vec(result.q[j]), "normal": _vec(result.u[j])}
            for j, lid in enumerate(result.landmark_ids)
        ],
        "space": {"lo": _vec(result.space_lo), "hi": _vec(result.space_hi)},
        "duration": float(t[-1]) if t.size else 0.0,
        "initial_poses": _poses(result, 0),
        "final_poses": _poses(result, -1),
        "initial_partition": _partition(result, result.owners[0].astype(np.intp)),
        "final_partition": _partition(result, result.final_owner),
        "coverage": np.column_stack([t, result.coverage]).tolist(),
        "visibility": result.visibility,
        "coverage_by_model": None if (by := result.coverage_by_model) is None else {
            name: np.column_stack([t, by[:, k]]).tolist()
            for k, name in enumerate(("facing", "occlusion"))},
        "vision": {
            aid: np.column_stack([t, result.vision[:, i]]).tolist()
            for i, aid in enumerate(result.agent_ids)
        },
        "trades": [
            {
                "t": float(e.t), "initiator": e.initiator, "partner": e.partner,
                "to_partner": [int(x) for x in e.to_partner],
                "to_initiator": [int(x) for x in e.to_initiator], "gain": float(e.gain),
            }
            for e in result.trades
        ],
        "complete": bool(result.complete),
        "t_complete": None if result.t_complete is None else float(result.t_complete),
        "checks": _checks(result),
        **inspection_document(result),
        "time_axis": {"scale": float(result.time_scale),
                      "wall_origin": None if result.wall_origin is None
                      else float(result.wall_origin),
                      "clock_offsets": {a: float(o) for a, o in result.clock_offsets.items()}},
    }


# ---------------------------------------------------------------------------------------
# Vision map (figure 5.2b-c).
# ---------------------------------------------------------------------------------------


def _sampled_vision(points: Array, q: Array, u: Array, d_opt: float, n_dir: int = 180
                    ) -> Array:
    """max over ``n_dir`` planar directions of vis(p, v, Q), for each row of ``points``."""
    term = as_distance_term(d_opt)
    ang = 2.0 * np.pi * np.arange(n_dir) / n_dir
    dirs = np.stack([np.cos(ang), np.sin(ang), np.zeros(n_dir)], axis=1)  # (D, 3)
    out = np.empty(points.shape[0])
    chunk = max(1, 2_000_000 // max(1, q.shape[0] * n_dir))
    for s in range(0, points.shape[0], chunk):  # chunks of grid points bound the memory
        d = q[None, :, :] - points[s:s + chunk, None, :]  # (N, m, 3)
        r = np.linalg.norm(d, axis=-1)
        pu = np.maximum(-np.einsum("nmk,mk->nm", d, u), 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.where(r > 0.0, term.fbar(np.where(r > 0.0, r, 1.0)) * pu, 0.0)
        dv = np.maximum(d @ dirs.T, 0.0)  # (N, m, D)
        out[s:s + chunk] = np.einsum("nm,nmd->nd", w, dv).max(axis=1)
    return out


def vision_map(xs: Array, ys: Array, q: Array, u: Array, d_opt: float) -> Array:
    """vis(p, v_opt(p), Q) on the planar grid ``xs`` × ``ys`` [m] (z = 0), shape (ny, nx).

    Algorithm 1 (exact) when m ≤ :data:`EXACT_MAP_MAX_LANDMARKS`, else the maximum over
    180 sampled yaw directions (vectorised over grid points and landmarks).
    """
    gx, gy = np.meshgrid(xs, ys)
    pts = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    if q.shape[0] > EXACT_MAP_MAX_LANDMARKS:
        return _sampled_vision(pts, q, u, d_opt).reshape(gx.shape)
    vals = np.empty(pts.shape[0])
    for k, p in enumerate(pts):  # Algorithm 1 is per point; the landmarks are vectorised
        v = optimal_orientation(p, q, u, d_opt)
        vals[k] = vision(p, v, q, u, d_opt) if v.any() else 0.0
    return vals.reshape(gx.shape)


# ---------------------------------------------------------------------------------------
# Plots.
# ---------------------------------------------------------------------------------------


def _colour(i: int) -> str:
    return f"C{i % 10}"


def _new_figure(size: tuple[float, float] = (7.0, 6.0)) -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)  # attaches itself to fig
    return fig


def _extent_2d(result: SimResult) -> tuple[Array, Array]:
    pts = [result.positions[..., :2].reshape(-1, 2), result.q[:, :2]]
    for corner in (result.space_lo[:2], result.space_hi[:2]):
        if np.all(np.isfinite(corner)):
            pts.append(corner[None, :])
    allp = np.vstack(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.08 * float(np.max(hi - lo)) + 0.5
    return lo - pad, hi + pad


def _draw_space_2d(ax: Axes, result: SimResult) -> None:
    lo, hi = result.space_lo[:2], result.space_hi[:2]
    if np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)):
        xs = [lo[0], hi[0], hi[0], lo[0], lo[0]]
        ys = [lo[1], lo[1], hi[1], hi[1], lo[1]]
        ax.plot(xs, ys, color="k", lw=2.0, label="mission space")


def _draw_landmarks_2d(ax: Axes, result: SimResult, colours: list[str] | None = None,
                       arrow: float = 0.3) -> None:
    q, u = result.q, result.u
    c = colours if colours is not None else ["k"] * q.shape[0]
    ax.scatter(q[:, 0], q[:, 1], c=c, marker="s", s=30, zorder=4, label="landmarks")
    ax.quiver(q[:, 0], q[:, 1], u[:, 0], u[:, 1], color=c, angles="xy", scale_units="xy",
              scale=1.0 / arrow, width=0.004, zorder=4)
    for j, lid in enumerate(result.landmark_ids):
        ax.annotate(str(lid), (float(q[j, 0]), float(q[j, 1])), textcoords="offset points",
                    xytext=(4, 4), fontsize=7)


def _plot_trajectories_2d(result: SimResult, path: Path) -> None:
    fig = _new_figure()
    ax = fig.add_subplot()
    lo, hi = _extent_2d(result)
    mine = result.owners[0].astype(np.intp) == 0
    if mine.any():
        n = 50 if int(mine.sum()) <= EXACT_MAP_MAX_LANDMARKS else 120
        xs, ys = np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n)
        vm = vision_map(xs, ys, result.q[mine], result.u[mine], result.d_opt)
        cs = ax.contourf(xs, ys, vm, levels=20, cmap="Greys", alpha=0.8)
        fig.colorbar(cs, ax=ax, label=f"vision of {result.agent_ids[0]}'s initial set")
    _draw_space_2d(ax, result)
    _draw_landmarks_2d(ax, result)
    span = float(np.max(hi - lo))
    for i, aid in enumerate(result.agent_ids):
        p = result.positions[:, i]
        v = result.directions[-1, i]
        ax.plot(p[:, 0], p[:, 1], color=_colour(i), lw=1.5, label=f"agent {aid}")
        ax.plot(p[0, 0], p[0, 1], "o", color=_colour(i), ms=6)
        ax.plot(p[-1, 0], p[-1, 1], "*", color=_colour(i), ms=10)
        ax.arrow(p[-1, 0], p[-1, 1], 0.06 * span * v[0], 0.06 * span * v[1],
                 color=_colour(i), width=0.004 * span, length_includes_head=True)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{result.scenario}: trajectories (o start, * end)")
    ax.legend(loc="best", fontsize=8)
    fig.savefig(path, dpi=110)


def _box_edges(lo: Array, hi: Array) -> list[Array]:
    """The 12 edges of the box [lo, hi] as (2, 3) segments."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    diff = np.abs(corners[:, None, :] - corners[None, :, :]) > 0
    i, j = np.nonzero(np.triu(diff.sum(axis=-1) == 1))
    return [corners[[a, b]] for a, b in zip(i, j, strict=True)]


def _setup_3d(ax: Any, result: SimResult) -> None:
    """Axes [m] zoomed on the structure (landmarks and final camera positions); paths and
    the mission space's edges are clipped there."""
    pts = np.vstack([result.positions[-1], result.q])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    if np.all(np.isfinite(result.space_lo)) and np.all(np.isfinite(result.space_hi)):
        for seg in _box_edges(result.space_lo, result.space_hi):
            ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], color="0.6", lw=0.8, axlim_clip=True)
    metric_axes_3d(ax, lo, hi, 0.1 * float(np.max(hi - lo)) + 0.3)


def _draw_landmarks_3d(ax: Any, result: SimResult, colours: list[str] | None = None) -> None:
    q, u = result.q, result.u
    c = colours if colours is not None else ["k"] * q.shape[0]
    ax.scatter(q[:, 0], q[:, 1], q[:, 2], c=c, marker="s", s=15, label="landmarks")
    ax.quiver(q[:, 0], q[:, 1], q[:, 2], u[:, 0], u[:, 1], u[:, 2], length=0.2, colors=c)
    if q.shape[0] <= LABEL_MAX_LANDMARKS:  # one text per landmark: matplotlib has no batch
        for j, lid in enumerate(result.landmark_ids):
            ax.text(*(q[j] + 0.12 * u[j]), str(lid), fontsize=7, axlim_clip=True)


def _draw_cameras_3d(ax: Any, result: SimResult, k: int) -> None:
    p, v = result.positions[k], result.directions[k]
    cols = [_colour(i) for i in range(p.shape[0])]
    ax.quiver(p[:, 0], p[:, 1], p[:, 2], v[:, 0], v[:, 1], v[:, 2], length=0.5, colors=cols)


def _plot_trajectories_3d(result: SimResult, path: Path) -> None:
    fig = _new_figure((8.0, 7.0))
    ax = fig.add_subplot(projection="3d")
    _setup_3d(ax, result)
    _draw_landmarks_3d(ax, result)
    for i, aid in enumerate(result.agent_ids):
        p = result.positions[:, i]
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color=_colour(i), lw=1.5, label=f"agent {aid}",
                axlim_clip=True)
        ax.scatter(p[[0], 0], p[[0], 1], p[[0], 2], color=_colour(i), marker="o",
                   axlim_clip=True)
        ax.scatter(p[[-1], 0], p[[-1], 1], p[[-1], 2], color=_colour(i), marker="*", s=60)
    _draw_cameras_3d(ax, result, -1)
    ax.set_title(f"{result.scenario}: trajectories (o start, * end)")
    ax.legend(loc="upper left", fontsize=8)
    fig.savefig(path, dpi=110)


def _plot_coverage(result: SimResult, path: Path) -> None:
    fig = _new_figure((8.0, 6.0))
    ax, ax2 = fig.subplots(2, 1, sharex=True)
    t = result.times
    ax.plot(t, result.coverage, color="k", lw=1.5,
            label=f"coverage (eq. 3.10, {result.visibility})")
    by = result.coverage_by_model
    if by is not None and len(by) == len(t):  # structure runs: under both models
        for k, (name, style) in enumerate((("facing", ":"), ("occlusion", "--"))):
            ax.plot(t, by[:, k], color="C0" if k == 0 else "C1", ls=style, lw=1.0,
                    label=f"under the {name} model")
    for k, e in enumerate(result.trades):
        ax.axvline(e.t, color="C3", ls="--", lw=0.8, label="trade" if k == 0 else None)
        ax2.axvline(e.t, color="C3", ls="--", lw=0.8)
    if result.t_complete is not None:
        ax.axvline(result.t_complete, color="C2", lw=1.0, label="complete")
    ax.set_ylabel("coverage score")
    ax.set_title(f"{result.scenario}: coverage ({len(result.trades)} trades)")
    ax.legend(loc="lower right", fontsize=8)
    for i, aid in enumerate(result.agent_ids):
        ax2.plot(t, result.vision[:, i], color=_colour(i), label=f"vision {aid}")
    ax2.set_xlabel("mission time τ [s]")
    ax2.set_ylabel("vision of own set")
    ax2.legend(loc="lower right", fontsize=8)
    fig.savefig(path, dpi=110)


def _plot_partition(result: SimResult, path: Path) -> None:
    owner = result.final_owner
    cols = [_colour(int(i)) for i in owner]
    if result.planar:
        fig = _new_figure()
        ax = fig.add_subplot()
        _draw_space_2d(ax, result)
        _draw_landmarks_2d(ax, result, cols, arrow=0.15)
        p, v = result.positions[-1], result.directions[-1]
        lo, hi = _extent_2d(result)
        span = float(np.max(hi - lo))
        for i, aid in enumerate(result.agent_ids):
            ax.plot(p[i, 0], p[i, 1], "o", color=_colour(i), ms=8, label=f"agent {aid}")
            ax.arrow(p[i, 0], p[i, 1], 0.08 * span * v[i, 0], 0.08 * span * v[i, 1],
                     color=_colour(i), width=0.004 * span, length_includes_head=True)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    else:
        fig = _new_figure((8.0, 7.0))
        ax = fig.add_subplot(projection="3d")
        _setup_3d(ax, result)
        _draw_landmarks_3d(ax, result, cols)
        p = result.positions[-1]
        for i, aid in enumerate(result.agent_ids):
            ax.scatter(p[[i], 0], p[[i], 1], p[[i], 2], color=_colour(i), s=40,
                       label=f"agent {aid}")
        _draw_cameras_3d(ax, result, -1)
    ax.set_title(f"{result.scenario}: final partition (landmarks coloured by owner)")
    ax.legend(loc="upper left", fontsize=8)
    fig.savefig(path, dpi=110)


def write_report(result: SimResult, out_dir: Path, plots: bool = True,
                 missing: str | None = None) -> list[Path]:
    """Write ``result.json`` (and the PNG plots unless ``plots=False``) into ``out_dir``
    (created if needed); returns the written paths. ``missing`` (a recording without agent
    states): said in result.json's ``missing``; no coverage, vision, trades nor final
    partition there, and the trajectories plot only."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = [out_dir / "result.json"]
    doc = result_document(result)
    if missing is not None:
        doc.update(missing=missing, coverage=[], coverage_by_model=None, trades=[],
                   vision={a: [] for a in result.agent_ids}, final_partition=None)
    written[0].write_bytes(msgspec.json.encode(doc) + b"\n")
    if plots:
        traj = out_dir / "trajectories.png"
        if result.planar:
            _plot_trajectories_2d(result, traj)
        else:
            _plot_trajectories_3d(result, traj)
        written.append(traj)
        if missing is not None:
            return written
        cov, part = out_dir / "coverage.png", out_dir / "partition.png"
        _plot_coverage(result, cov)
        _plot_partition(result, part)
        written += [cov, part]
        if result.inspection is not None:
            written.append(out_dir / "captures.png")
            plot_captures(result, written[-1])
    return written
