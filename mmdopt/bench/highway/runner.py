"""One episode, the resumable sweep behind ``mmdopt bench highway`` and the video writer."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

import mmdopt
from mmdopt.planner import PLANNERS
from mmdopt.receding import RecedingConfig, run_receding, warm_up
from mmdopt.risk import check_risk, config_for_risk

from ..executors import EXECUTORS, MISSING, check_manifest, run_tasks, worker_layout
from ..results import write_json
from .adapter import HighwaySource, bicycle_limits
from .settings import (
    AGENTS,
    JUNCTION_SHIELD,
    METHODS,
    SHIELD,
    HighwaySettings,
    check_env_config,
    highway_config,
)

CSV_COLUMNS = (
    "episode",
    "seed",
    "env",
    "method",
    "predictor",
    "crashed",
    "mean_speed",
    "distance_m",
    "duration_s",
    "mean_plan_s",
    "max_plan_s",
    "median_plan_s",
    "over_budget",
    "steps",
    "mean_predict_s",
    "max_predict_s",
    "first_plan_s",
    "fallbacks",
    "crash_kind",
    "tracking_error_m",
    "between_lanes_s",
    "interventions",
    "off_road",
    "risk",
    "mean_risk_bound",
    "arrived",
)


# ------------------------------------------------------------------------------------ one episode
def run_episode(
    episode: int,
    seed: int,
    method: str,
    settings: HighwaySettings,
    config: mmdopt.MMDOptConfig,
    *,
    render: bool = False,
    callback=None,
) -> dict[str, Any]:
    """Drive one episode with the agent ``method`` (:data:`~.settings.AGENTS`); the episode
    record (a JSON-friendly dict with the CSV columns, per-step plan and predictor times, and the
    frames and their views when ``render``).  ``callback(i, observation, plan, outcome)`` is
    :func:`mmdopt.receding.run_receding`'s, after each replan (not called for the IDM driver)."""
    import jax

    src = HighwaySource(settings, seed, config, method=method, render=render)
    t_start = time.perf_counter()
    agent = src.agent
    if agent.driver == "idm":
        predictor = "-"  # no predictor
    else:
        predictor = settings.predictor if agent.predictor is None else agent.predictor
    rec: dict[str, Any] = {
        "episode": int(episode),
        "seed": int(seed),
        "env": settings.env,
        "method": method,
        "predictor": predictor,
    }
    plan_times: list[float] = []
    first_plan = float("nan")
    fallbacks = interventions = 0
    shield_reasons: list[str] = []
    steps_status: list[str] = []
    if agent.driver == "idm":
        out = src.run_idm()
        crashed = out.crashed
    else:
        rc = RecedingConfig(
            dt=settings.dt,
            budget_s=settings.budget_s,
            method=agent.plan_method,
            max_obstacles=settings.max_obstacles,
            max_steps=int(math.ceil(settings.duration / settings.dt)) + 1,
            shield=(SHIELD if src.route is None else JUNCTION_SHIELD) if settings.shield else None,
        )
        planner, first_plan = _warmed_planner(src, rc, config, seed, settings.max_obstacles)
        res = run_receding(
            src, rc, key=jax.random.PRNGKey(seed), callback=callback, planner=planner
        )
        crashed = res.crashed
        plan_times = [float(x) for x in res.plan_times]
        fallbacks = sum(r.fallback for r in res.steps)
        steps_status = [r.status for r in res.steps if r.status != "ok"]
        interventions = sum(r.intervened for r in res.steps)
        shield_reasons = [f"t={r.time:.1f} s: {r.shield}" for r in res.steps if r.intervened]
        rec["plan_d"] = [r.d for r in res.steps]  # lateral offset at each replan (m)
        bounds = np.array([r.risk_bound for r in res.steps], float)
        bounds = bounds[np.isfinite(bounds)]
        rec["mean_risk_bound"] = float(bounds.mean()) if bounds.size else None
        for name in ("reduced_set_s", "cem_s"):
            rec[name] = [r.timings.get(name, float("nan")) for r in res.steps]
    pt = np.array(plan_times) if plan_times else np.array([np.nan])
    pr = np.array(src.predict_times) if src.predict_times else np.array([np.nan])
    speeds = np.array(src.speeds)
    # None where it does not apply (the IDM ego tracks no plan)
    errors = getattr(src.ego, "tracking_errors", None)
    limits = np.array(src.plan_limits).reshape(-1, 2)
    rec.update(
        risk=float(config.safety.risk)
        if agent.driver != "idm" and config.safety.margins.margin_mode == "samples"
        else None,
        crashed=bool(crashed),
        mean_speed=float(speeds.mean()),
        distance_m=src.distance(),
        duration_s=float(src.env.time),
        mean_plan_s=float(pt.mean()),
        max_plan_s=float(pt.max()),
        median_plan_s=float(np.median(pt)),
        over_budget=int(np.sum(pt > settings.budget_s)),
        steps=len(plan_times),
        mean_predict_s=float(pr.mean()),
        max_predict_s=float(pr.max()),
        first_plan_s=first_plan,
        fallbacks=int(fallbacks),
        crash_kind=src.crash_kind,
        plan_times=plan_times,
        predict_times=[float(x) for x in src.predict_times],
        speeds=[float(x) for x in speeds],
        statuses=steps_status[:20],
        wall_s=time.perf_counter() - t_start,
        tracking_error_m=float(np.mean(errors)) if errors else None,
        max_tracking_error_m=float(np.max(errors)) if errors else None,
        between_lanes_s=float(src.between_lanes_s),
        interventions=int(interventions),
        off_road=bool(src.off_road),
        arrived=src.arrived,
        # other cars crashed among themselves by the episode's end (a wreck in a junction
        # blocks every route through it, the ego's included)
        others_crashed=src.others_crashed(),
        shield=shield_reasons[:20],
        ego_model=settings.ego_model,
        max_plan_curvature=float(np.max(limits[:, 0])) if limits.size else None,
        max_plan_yaw_rate=float(np.max(limits[:, 1])) if limits.size else None,
        curvature_limit=bicycle_limits(),
    )
    if render:
        rec["frames"] = src.frames
        rec["frame_views"] = src.frame_views
    src.close()
    return rec


def _warmed_planner(src: HighwaySource, rc: RecedingConfig, config, seed: int, max_obstacles: int):
    """The config's planner (on the process's shared workspaces: episodes compile once) and the
    wall time of compiling it on the episode's first scene, untimed by the loop: with the
    time-linear margins the shapes are fixed by ``max_obstacles``; on the risk dial (no
    phantoms) each number of cars 1 … ``max_obstacles`` is a shape, and so is an empty road (the
    planner's own phantom on the source's ``n_samples`` futures), each compiled once per process
    (:data:`_WARMED`; the cars in turn need a first scene with a car).  The source is rewound to
    its first replan."""
    import jax

    obs0 = src.observe()
    planner = PLANNERS.get(config)
    key = jax.random.PRNGKey(seed)
    dial = config.safety.margins.margin_mode == "samples"
    done = _WARMED.setdefault(config, set()) if dial else set()
    fc = obs0.obstacles
    cars = fc.num_obstacles if isinstance(fc, mmdopt.predict.Forecast) else np.shape(fc)[0]
    counts = [k for k in range(1, int(max_obstacles) + 1) if k not in done] if dial and cars else []
    first = warm_up(obs0, rc, key=key, planner=planner, counts=counts)
    done.update(counts)
    if dial and 0 not in done:  # an empty road
        K = config.trajectory.num_steps
        empty = dataclasses.replace(
            obs0, obstacles=np.zeros((0, src.settings.n_samples, K, 2)), obstacle_headings=None,
            obstacle_states=None,
        )  # fmt: skip
        first += warm_up(empty, rc, key=key, planner=planner)
        done.add(0)
    src.predict_times.clear()
    src.step_index = 0
    return planner, first


# ------------------------------------------------------------------------------------ the sweep
#: the shapes each planner config on the risk dial has been warmed up for in this process: the
#: numbers of cars (0: an empty road)
_WARMED: dict[mmdopt.MMDOptConfig, set[int]] = {}


def _episode_path(out: Path, episode: int, method: str) -> Path:
    return out / "episodes" / f"episode_{episode:04d}__{method}.json"


def _manifest(settings: HighwaySettings, config_overrides: dict, seed: int) -> dict:
    """What a folder's episodes were made with: the settings, the overrides, the seed and the
    planner they resolve to (:meth:`mmdopt.MMDOptConfig.highway` with the overrides, in full),
    so that a folder made under another version's preset refuses to be resumed."""
    config = highway_config(config_overrides)
    planner = config.to_dict()
    samples = config.safety.margins.margin_mode == "samples"
    return json.loads(
        json.dumps(
            {
                "predictor": settings.predictor,
                "risk": float(config.safety.risk) if samples else None,
                "margin_mode": config.safety.margins.margin_mode,
                "settings": asdict(settings),
                "config": config_overrides,
                "seed": int(seed),
                "planner": planner,
            }
        )
    )


def risk_overrides(overrides: dict | None, risk: float | None) -> dict:
    """``overrides`` with the risk mode at ε = ``risk`` (``--risk``): sample-driven margins
    (``margin_mode = "samples"``) and ``safety.risk = ε``, nested as the config file's sections;
    ``risk = None``: ``overrides`` unchanged."""
    out = json.loads(json.dumps(overrides or {}))
    if risk is None:
        return out
    eps = check_risk(risk, "risk")
    safety = out.setdefault("safety", {})
    if not isinstance(safety, dict):
        raise ValueError("config section 'safety' must be an object to add --risk to it")
    safety["risk"] = eps
    safety.setdefault("margins", {})["margin_mode"] = "samples"
    return out


def config_for_method(method: str, config: mmdopt.MMDOptConfig) -> mmdopt.MMDOptConfig:
    """The planner of ``method`` (an agent of :data:`METHODS`) in an episode: in the risk mode
    (``margin_mode = "samples"``) the method's own mapping of ``safety.risk``
    (:func:`mmdopt.risk.config_for_risk`: its margins, weights and re-selection); otherwise
    ``config`` as it is."""
    plan_method = AGENTS[method].plan_method if method in AGENTS else None
    if plan_method is None or config.safety.margins.margin_mode != "samples":
        return config
    return config_for_risk(plan_method, float(config.safety.risk), config)


def _task(args) -> str:
    episode, seed, method, settings_d, overrides, out, progress = args
    settings = HighwaySettings(**settings_d)
    config = highway_config(overrides)
    rec = run_episode(episode, seed, method, settings, config_for_method(method, config))
    write_json(_episode_path(Path(out), episode, method), rec)
    line = _progress_line(rec)
    if progress:
        print(line, flush=True)
    return line


def write_csv(rows: Sequence[dict], path: Path) -> None:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(CSV_COLUMNS), extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in CSV_COLUMNS})


def _nanmean(values) -> float:
    """Mean of the finite values (NaN when none: e.g. the IDM ego has no tracking error)."""
    v = np.array([np.nan if x is None else float(x) for x in values], dtype=float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else float("nan")


def _arrived_share(rows) -> float:
    """The share of episodes whose ego reached its destination (NaN on roads without one)."""
    flags = [r.get("arrived") for r in rows if r.get("arrived") is not None]
    return float(np.mean([bool(f) for f in flags])) if flags else float("nan")


def summarize(rows: Sequence[dict]) -> list[dict]:
    """Per method: episodes, crashes, mean speed, mean distance, median/mean/max plan time, mean
    tracking error and time between lanes per episode, shield interventions in all, and the
    share of episodes that arrived (at a junction; NaN on roads without a destination)."""
    out = []
    for m in dict.fromkeys(r["method"] for r in rows):
        rs = [r for r in rows if r["method"] == m]
        pts = np.concatenate([np.asarray(r.get("plan_times") or [np.nan]) for r in rs])
        pts = pts[np.isfinite(pts)]
        prs = np.concatenate([np.asarray(r.get("predict_times") or [np.nan]) for r in rs])
        prs = prs[np.isfinite(prs)]
        out.append(
            {
                "method": m,
                "episodes": len(rs),
                "crashes": int(sum(bool(r["crashed"]) for r in rs)),
                "mean_speed": float(np.mean([r["mean_speed"] for r in rs])),
                "distance_m": float(np.mean([r["distance_m"] for r in rs])),
                "median_plan_s": float(np.median(pts)) if pts.size else float("nan"),
                "mean_plan_s": float(np.mean(pts)) if pts.size else float("nan"),
                "max_plan_s": float(np.max(pts)) if pts.size else float("nan"),
                "median_predict_s": float(np.median(prs)) if prs.size else float("nan"),
                "tracking_error_m": _nanmean(r.get("tracking_error_m") for r in rs),
                "between_lanes_s": _nanmean(r.get("between_lanes_s") for r in rs),
                "interventions": int(sum(int(r.get("interventions") or 0) for r in rs)),
                "arrived": _arrived_share(rs),
            }
        )
    return out


def run_highway(
    out: str | Path,
    *,
    episodes: int,
    seed: int = 0,
    methods: Sequence[str] = ("mmd", "idm"),
    settings: HighwaySettings | None = None,
    config_overrides: dict | None = None,
    executor: str = "local",
    jobs: int = 1,
    address: str | None = None,
    progress: bool = True,
    isolate: bool = False,
    risk: float | None = None,
) -> list[dict]:
    """Resumable benchmark: episode ``i`` uses seed ``seed + i``; each finished (episode, method)
    is ``OUT/episodes/episode_XXXX__METHOD.json`` and never recomputed; ``OUT/episodes.csv`` is
    rebuilt from them.  Reusing ``out`` with other settings is refused (``ValueError``).  The
    environment id is checked (:func:`~.settings.check_env`) before anything is written;
    ``isolate`` as in :func:`~mmdopt.bench.executors.run_tasks` (recorded in the manifest).
    ``risk`` ε: the planners in the risk mode at ε (:func:`risk_overrides`, recorded in the
    manifest's config; each method's own mapping of ε, :func:`config_for_method`); with a
    forecast (the default) each replan draws n(ε) futures per car, at most
    :data:`~.adapter.MAX_FORECAST_SAMPLES`."""
    settings = HighwaySettings() if settings is None else settings
    overrides = risk_overrides(config_overrides, risk)
    highway_config(overrides)  # validate before starting
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be an int >= 1, got {episodes!r}")
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ValueError(f"methods must be among {METHODS}, got {list(methods)}")
    if executor not in EXECUTORS:
        raise ValueError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    check_env_config(settings.env, settings.env_config)
    out = Path(out)
    (out / "episodes").mkdir(parents=True, exist_ok=True)
    man = dict(_manifest(settings, overrides, seed), workers=worker_layout(jobs, executor, isolate))
    # folders written before the manifest recorded where episodes ran, or the planner
    check_manifest(
        out,
        man,
        aliases={
            "workers": [MISSING],
            "planner": [MISSING],
            "predictor": [MISSING],
            "risk": [MISSING],
            "margin_mode": [MISSING],
        },
    )
    todo = [
        (i, seed + i, m, asdict(settings), overrides, str(out), progress)
        for i in range(episodes)
        for m in methods
        if not _episode_path(out, i, m).exists()
    ]
    run_tasks(
        _task,
        todo,
        jobs=jobs,
        executor=executor,
        address=address,
        progress=False,
        desc="episodes",
        unit="episode",
        isolate=isolate,
    )
    rows = []
    for i in range(episodes):
        for m in methods:
            p = _episode_path(out, i, m)
            if p.exists():
                rows.append(json.loads(p.read_text()))
    write_csv(rows, out / "episodes.csv")
    (out / "summary.json").write_text(json.dumps(summarize(rows), indent=1))
    return rows


def _progress_line(r) -> str:
    return (
        f"  episode {r['episode']} seed {r['seed']} {r['method']}: "
        f"crashed={r['crashed']} mean_speed={r['mean_speed']:.2f} m/s "
        f"median_plan={r['median_plan_s']:.3f} s predict={r['mean_predict_s']:.3f} s"
    )


def write_video(
    path: str | Path,
    episode: int,
    seed: int,
    method: str,
    settings: HighwaySettings,
    config: mmdopt.MMDOptConfig,
) -> Path:
    """Render one episode (highway-env's ``rgb_array``) with the planner drawn on it (the executed
    plan, the predicted futures with the reduced set highlighted, method, time, speed and status:
    :mod:`.video`) to ``path``: MP4 when imageio's ffmpeg plugin is installed and ``path`` ends
    in ``.mp4``, otherwise a GIF (suffix replaced).  Returns the path written."""
    from . import video

    video.headless_display()
    recorder = video.PlanRecorder()
    rec = run_episode(episode, seed, method, settings, config, render=True, callback=recorder)
    if not rec["frames"] or any(f is None for f in rec["frames"]):
        raise RuntimeError("highway-env rendered no frames")
    frames = video.overlay_episode(
        [np.asarray(f) for f in rec["frames"]],
        rec["frame_views"],
        recorder.steps,
        method=method,
        speeds=rec["speeds"],
        frame_dt=1.0 / settings.simulation_frequency,
        frames_per_step=settings.frames_per_step,
    )
    return video.encode(path, frames, fps=settings.simulation_frequency)
