"""``mmdopt bench highway``: :func:`add_highway_parser` and :func:`cmd_highway`."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..argtypes import add_executor, method_list, nonneg_int, positive_float, positive_int
from ..inputs import read_json
from .runner import run_highway, summarize, write_video
from .settings import (
    EGO_MODELS,
    METHODS,
    PREDICTORS,
    HighwaySettings,
    check_env,
    check_env_config,
    default_predictor,
    highway_available,
    highway_config,
)


# ------------------------------------------------------------------------------------------ CLI
def add_highway_parser(bench_subparsers):
    """Add ``highway`` to the ``mmdopt bench`` sub-commands; returns the parser."""
    h = bench_subparsers.add_parser(
        "highway",
        help="closed-loop receding-horizon driving in highway-env",
        description="Receding-horizon MMD-Opt and baselines driving in highway-env; "
        "resumable, one JSON per episode, DIR/episodes.csv.",
    )
    h.add_argument("--episodes", type=positive_int, default=20, help="episodes (default 20)")
    h.add_argument("--seed", type=nonneg_int, default=0, help="episode i uses seed S + i")
    h.add_argument("--duration", type=positive_float, default=20.0, help="seconds per episode")
    h.add_argument("--out", required=True, help="output folder (resumable)")
    h.add_argument("--env", default="highway-v0", help="highway-env id (default highway-v0)")
    h.add_argument(
        "--env-config",
        default=None,
        metavar="FILE.json",
        help='JSON object of the env\'s own config keys, e.g. {"vehicles_density": 2} '
        "(keys of its default_config(); recorded in the manifest)",
    )
    h.add_argument(
        "--methods",
        type=method_list(METHODS),
        default=["mmd", "degroot", "cv", "idm"],
        help="comma-separated: mmd,degroot,cv,idm (default all)",
    )
    h.add_argument(
        "--predictor",
        choices=PREDICTORS,
        default=None,
        help="sim: the simulator oracle (rollouts of highway-env's own driver models); cv: "
        "constant velocity; learned: the MDN trained on highway-env rollouts of seeds >= 100000; "
        "route: one mode per route a car can take from its lane through a junction, uniform "
        "weights (default: route at a junction, intersection-* and roundabout-*; else learned)",
    )
    h.add_argument(
        "--config",
        default=None,
        metavar="FILE.json",
        help="JSON object of MMDOptConfig fields on top of the highway defaults",
    )
    h.add_argument(
        "--dt", type=positive_float, default=0.5, help="replan period δ (s, default 0.5)"
    )
    h.add_argument("--samples", type=positive_int, default=20, help="predictor samples per car")
    h.add_argument(
        "--risk",
        type=float,
        default=None,
        metavar="EPS",
        help="plan in the risk mode at collision probability EPS in (0, 0.5): the preset with "
        "sample-driven margins, each method's mapping of EPS, n(EPS) futures per car drawn "
        "from the predictor each replan (at most 5000) and a risk bound per replan "
        "(default: the preset's time-linear margins)",
    )
    h.add_argument(
        "--ego-model",
        choices=EGO_MODELS,
        default="bicycle",
        help="bicycle: highway-env's kinematic bicycle steered by a tracking controller; "
        "exact: the ego's pose set from the plan, no vehicle model (default bicycle)",
    )
    h.add_argument(
        "--no-shield",
        action="store_true",
        help="run plans unchecked (default: the RSS safe-distance shield of mmdopt.safety)",
    )
    h.add_argument(
        "--no-forecast",
        action="store_true",
        help="give the planner each replan's drawn futures (default: a forecast of the "
        "predictor, mmdopt.predict.Forecast, that the loop draws from: n_samples futures with "
        "the time-linear margins, n(ε) in the 'samples' margin mode)",
    )
    add_executor(h)
    h.add_argument("--jobs", type=positive_int, default=1, help="parallel episodes (default 1)")
    h.add_argument(
        "--video",
        type=nonneg_int,
        default=None,
        metavar="EPISODE",
        help="also write DIR/video_EPISODE_METHOD.gif (or .mp4) of this episode",
    )
    h.add_argument("--no-progress", action="store_true")
    h.set_defaults(func=cmd_highway)
    return h


def _json_file(path, option: str):
    """The JSON value of the file given to ``option`` (:func:`~..inputs.read_json`);
    ``ValueError`` naming the option when it does not exist or is not JSON."""
    if not Path(path).is_file():
        raise ValueError(f"argument {option}: file {str(path)!r} does not exist")
    try:
        return read_json(path)
    except ValueError as e:
        raise ValueError(f"argument {option}: {e}") from None


def _load_overrides(path) -> dict:
    if path is None:
        return {}
    raw = _json_file(path, "--config")
    if not isinstance(raw, dict):
        raise ValueError(
            "argument --config: the config must be a JSON object of MMDOptConfig fields"
        )
    try:
        highway_config(raw)
    except (TypeError, ValueError) as e:
        raise ValueError(f"argument --config: {e}") from None
    return raw


def _load_env_config(path, env: str) -> dict:
    """The ``--env-config`` file's JSON object, checked against ``env``'s own config keys."""
    if path is None:
        return {}
    raw = _json_file(path, "--env-config")
    try:
        check_env_config(env, raw)
    except ValueError as e:
        raise ValueError(f"argument --env-config: {e}") from None
    return raw


def _fail(parser, msg: str) -> int:
    """Exit status 2 with ``msg``: ``parser.error`` (argparse's form) when there is a parser,
    else one line on stderr and 2 returned."""
    import sys

    if parser is not None:
        parser.error(msg)
    print(f"mmdopt bench highway: {msg}", file=sys.stderr)
    return 2


def cmd_highway(args, parser=None) -> int:
    """Run ``mmdopt bench highway``; prints a per-method table; returns the exit status.
    ``--config``, ``--env`` and ``--env-config`` are checked before anything is written (exit 2
    naming them)."""
    import sys

    if not highway_available():
        print(
            'mmdopt bench highway: highway-env is not installed; pip install -e ".[highway]"',
            file=sys.stderr,
        )
        return 2
    try:
        overrides = _load_overrides(args.config)
    except ValueError as e:
        return _fail(parser, str(e))
    try:
        check_env(args.env)
    except ValueError as e:
        return _fail(parser, f"argument --env: {e}")
    try:
        env_config = _load_env_config(getattr(args, "env_config", None), args.env)
    except ValueError as e:
        return _fail(parser, str(e))
    if getattr(args, "risk", None) is not None:
        from mmdopt.risk import check_risk

        try:
            check_risk(args.risk, "argument --risk")
        except ValueError as e:
            return _fail(parser, str(e))
    try:
        settings = HighwaySettings(
            env=args.env,
            env_config=env_config,
            duration=float(args.duration),
            dt=float(args.dt),
            n_samples=int(args.samples),
            ego_model=getattr(args, "ego_model", "bicycle"),
            shield=not getattr(args, "no_shield", False),
            forecast=not getattr(args, "no_forecast", False),
            predictor=args.predictor or default_predictor(args.env),
        )
    except ValueError as e:
        return _fail(parser, str(e))
    try:
        rows = run_highway(
            args.out,
            episodes=args.episodes,
            seed=args.seed,
            methods=args.methods,
            settings=settings,
            config_overrides=overrides,
            executor=args.executor,
            jobs=args.jobs,
            address=args.address,
            progress=not args.no_progress,
            isolate=True,
            risk=getattr(args, "risk", None),
        )
    except ValueError as e:
        return _fail(parser, str(e))
    summ = summarize(rows)
    cols = [
        "method",
        "episodes",
        "crashes",
        "mean_speed",
        "distance_m",
        "median_plan_s",
        "max_plan_s",
        "median_predict_s",
        "tracking_error_m",
        "between_lanes_s",
        "interventions",
    ]
    print("  ".join(f"{c:>14}" for c in cols))
    for s in summ:
        print(
            "  ".join(
                f"{s[c]:>14.3f}" if isinstance(s[c], float) else f"{s[c]!s:>14}" for c in cols
            )
        )
    print(f"wrote {Path(args.out) / 'episodes.csv'}")
    if args.video is not None:
        for m in args.methods:
            p = write_video(
                Path(args.out) / f"video_{args.video:04d}_{m}.mp4",
                args.video,
                args.seed + args.video,
                m,
                settings,
                highway_config(overrides),
            )
            print(f"wrote {p}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mmdopt.bench.highway [OPTIONS]``: the options of ``mmdopt bench highway``."""
    import argparse
    import sys

    p = argparse.ArgumentParser(prog="python -m mmdopt.bench.highway")
    add_highway_parser(p.add_subparsers(dest="experiment", required=True))
    args = p.parse_args(["highway", *(sys.argv[1:] if argv is None else argv)])
    return cmd_highway(args, p)
