"""Figures of the real-traffic benchmark: one scene on the real road geometry, plan time vs O."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import mmdopt
from mmdopt.bench.plots import method_colour, method_label, pyplot

from .inputs import NgsimParams, ngsim_config
from .metric import rect_corners
from .reactive import PEERS
from .runner import peer_plan, plan_inputs
from .scene import future_at

__all__ = ["ROUTE_COLOURS", "ngsim_scene_figure", "timing_vs_obstacles_figure"]


#: colours of a car's routes in the figures, the straightest first
ROUTE_COLOURS = ("tab:red", "tab:blue", "tab:purple", "tab:orange")


def ngsim_scene_figure(
    task: dict,
    path: str | Path,
    methods=("mmd", "degroot"),
    predictor: str = "learned",
    params: NgsimParams | None = None,
    config=None,
    n_draw: int = 20,
) -> Path:
    """Cartesian figure of one task exactly as ``bench ngsim`` plans it (:func:`plan_inputs`):
    lanelets, the ego's route (its reference path, thick grey), every obstacle's recorded future
    (black) and ``n_draw`` of its planning futures coloured by the route each follows (nearest
    route at the end; :data:`ROUTE_COLOURS`, the straightest red), the ego's recorded future
    (dashed) and each method's plan (``reactive`` too) with footprints at 0, 2.5 and 5 s."""
    plt = pyplot()
    p = NgsimParams() if params is None else params
    cfg = ngsim_config() if config is None else config
    inp = plan_inputs(task, p, cfg, predictor)
    b, cfg = inp.task, inp.config
    sc, v, k, times = b["scene"], b["v"], b["k"], b["times"]
    samples = np.asarray(inp.planned)[: len(b["obs"])]
    fig, ax = plt.subplots(figsize=(8, 8))
    _draw_lanelets(ax, task["scenario"], sc)
    path_xy = np.stack(
        [np.asarray(a) for a in b["road"].path.to_cartesian(*_path_grid(b["road"].path))], -1
    )
    ax.plot(path_xy[:, 0], path_xy[:, 1], color="0.45", lw=5, alpha=0.35, zorder=2)
    ax.plot([], [], color="0.45", lw=5, alpha=0.35, label="ego route (reference path)")
    used = set()
    for o in range(samples.shape[0]):
        routes = b["routes"][o]
        for j in range(min(n_draw, samples.shape[1])):
            end = samples[o, j, -1]
            r = int(np.argmin([np.min(np.linalg.norm(rt - end, axis=-1)) for rt in routes]))
            used.add(r)
            col = ROUTE_COLOURS[min(r, len(ROUTE_COLOURS) - 1)]
            ax.plot(samples[o, j, :, 0], samples[o, j, :, 1], color=col, alpha=0.15, lw=0.7)
    for r in sorted(used):
        name = "straightest route" if r == 0 else f"route {r + 1}"
        ax.plot(
            [], [], color=ROUTE_COLOURS[min(r, 3)], alpha=0.5,
            label=f"planning futures, {name} ({n_draw}/car)",
        )  # fmt: skip
    others = np.flatnonzero(np.arange(len(sc.ids)) != v)
    fut = future_at(sc, others, k, times)
    for o in range(len(others)):
        ok = np.all(np.isfinite(fut[o]), -1)
        if ok.sum() > 1:
            ax.plot(fut[o, ok, 0], fut[o, ok, 1], color="k", lw=1.0, zorder=3)
        if ok[0]:
            i = others[o]
            c = rect_corners(*fut[o, 0], sc.heading[i, k], sc.length[i], sc.width[i])
            ax.fill(c[:, 0], c[:, 1], color="0.3", alpha=0.6, zorder=3)
    ax.plot([], [], color="k", lw=1.0, label="recorded futures (other vehicles)")
    rec = future_at(sc, [v], k, times)[0]
    ax.plot(
        rec[:, 0], rec[:, 1], "--", color="tab:green", lw=1.6, label="recorded human (ego car)",
        zorder=6,
    )  # fmt: skip
    pts = [rec]
    for m in methods:
        if m in PEERS:
            pl = peer_plan(task, inp, p.reactive_futures, p.reactive_full_horizon)
        else:
            pl = mmdopt.plan(
                b["ego"], b["road"], inp.obstacles, method=m, config=cfg, key=inp.key_plan
            )
        col = method_colour(m) or "tab:brown"
        ax.plot(pl.x, pl.y, color=col, lw=2.2, label=f"plan: {method_label(m)}", zorder=5)
        pts.append(pl.xy)
        for t_mark in (0.0, 2.5, 5.0):
            j = int(np.argmin(np.abs(times - t_mark)))
            c = rect_corners(pl.x[j], pl.y[j], pl.heading[j], sc.length[v], sc.width[v])
            ax.fill(c[:, 0], c[:, 1], facecolor="none", edgecolor=col, lw=1.2, zorder=5)
    allp = np.concatenate(pts, 0)
    lo, hi = allp.min(0) - 25.0, allp.max(0) + 25.0
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        f"{sc.name}, ego {task['ego_id']} at t0 = {task['t0']} s, "
        f"horizon {cfg.trajectory.horizon:g} s"
    )
    ax.legend(loc="upper left", fontsize=8, framealpha=0.9).set_zorder(100)  # over the road
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def _path_grid(path) -> tuple[np.ndarray, np.ndarray]:
    s = np.linspace(0.0, float(path.length), 300)
    return s, 0.0 * s


def _draw_lanelets(ax, scenario_path, sc) -> None:
    """The scene's lanelet network drawn by commonroad-io's ``MPRenderer`` on ``ax`` (lanelet
    surfaces and boundaries, under everything else); the lanelet boundary polylines of the
    loaded scene where the renderer is unavailable."""
    try:
        from commonroad.common.file_reader import CommonRoadFileReader
        from commonroad.visualization.mp_renderer import MPRenderer

        scenario, _ = CommonRoadFileReader(str(scenario_path)).open()
        rnd = MPRenderer(ax=ax)
        # no traffic signs / lights: the urban scenes' sign labels fail in its offset boxes
        rnd.draw_params.lanelet_network.traffic_sign.draw_traffic_signs = False
        rnd.draw_params.lanelet_network.traffic_light.draw_traffic_lights = False
        scenario.lanelet_network.draw(rnd)
        rnd.render()
        for c in [*ax.collections, *ax.patches, *ax.lines]:
            c.set_zorder(0)  # the road under the traffic and the plans
        ax.plot([], [], color="0.3", lw=0.8, label="lanelets (commonroad-io MPRenderer)")
    except ImportError:
        for lane in sc.lanes.values():
            for side in (lane.left, lane.right):
                ax.plot(side[:, 0], side[:, 1], color="0.6", lw=0.8, zorder=1)
        ax.plot([], [], color="0.6", lw=0.8, label="lanelet boundaries")


def timing_vs_obstacles_figure(rows, path: str | Path) -> Path:
    """Median plan time (s) against the number of obstacles, from
    :func:`~mmdopt.bench.ngsim.runner.timing_vs_obstacles` rows."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for m in sorted({r["method"] for r in rows}):
        rr = sorted((r for r in rows if r["method"] == m), key=lambda r: r["n_obstacles"])
        ax.plot(
            [r["n_obstacles"] for r in rr],
            [r["median_s"] for r in rr],
            "o-",
            color=method_colour(m),
            label=method_label(m),
        )
    ax.axhline(1.0, color="0.5", ls=":", label="1 s")
    ax.set_xlabel("obstacles planned against")
    ax.set_ylabel("median plan time (s)")
    ax.legend()
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path
