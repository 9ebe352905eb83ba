"""Command line of the real-traffic benchmark and of the predictor training.

::

    mmdopt bench ngsim --scenarios PATH [PATH ...] --out DIR [--methods mmd,degroot]
                       [--predictor learned|lane|cv] [--config FILE.json]
                       [--executor local|ray] [--jobs J] [--max-tasks N] [--export DIR]
    mmdopt predictor train [--data DIR] [--out PATH] [--steps N] [--seed S] [--no-eval]
    mmdopt predictor train --source highway [--episodes N] [--duration T] [--out PATH] ...
    mmdopt predictor eval  [--source ngsim|highway] [--data DIR] [--weights PATH] [--out FILE.json]

``--source highway`` trains on highway-env rollouts instead of the US-101 scenes
(:mod:`mmdopt.bench.highway.training`; seeds 100000 + i, the benchmark's episodes use seeds
below 100000) and evaluates on the held-out seeds 0 … 9.

``add_ngsim_parser(bench_subparsers)`` / ``cmd_ngsim(args)`` and ``add_train_parser(subparsers)``
/ ``cmd_train(args)`` / ``cmd_eval(args)`` plug into :mod:`mmdopt.bench.cli`; :func:`main` runs
them standalone (``python -m mmdopt.bench.ngsim.cli bench ngsim ...``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from ..argtypes import add_executor, existing_path, method_list, positive_float, positive_int

__all__ = [
    "add_ngsim_parser",
    "cmd_ngsim",
    "add_train_parser",
    "cmd_train",
    "cmd_eval",
    "default_data_dir",
    "default_training_data",
    "evaluate_heldout",
    "main",
]


def default_data_dir() -> Path:
    """``$MMDOPT_SHARED_DATA/ngsim_us101``, else ``../shared/data/ngsim_us101``."""
    root = os.environ.get("MMDOPT_SHARED_DATA")
    return Path(root) / "ngsim_us101" if root else Path("../shared/data/ngsim_us101")


def default_training_data() -> list[Path]:
    """What the shipped predictor is trained on: the US-101 folder (:func:`default_data_dir`)
    and, where it is there, the Lankershim one beside it (``ngsim_urban``)."""
    us = default_data_dir()
    urban = us.parent / "ngsim_urban"
    return [us] + ([urban] if urban.is_dir() else [])


def _ngsim_methods() -> tuple[str, ...]:
    """The planning methods of :mod:`mmdopt.methods` and the bench's peers (at parse time)."""
    import mmdopt.methods

    from .reactive import PEERS

    return (*mmdopt.methods.names(), *PEERS)


def add_ngsim_parser(bench_subparsers) -> argparse.ArgumentParser:
    """``bench ngsim``: MMD-Opt in recorded US-101 traffic (CommonRoad scenes)."""
    from mmdopt.predict import PREDICTORS

    q = bench_subparsers.add_parser(
        "ngsim", help="plan as a recorded car in recorded US-101 traffic (CommonRoad scenes)"
    )
    q.add_argument(
        "--scenarios",
        nargs="+",
        type=existing_path,
        required=True,
        metavar="PATH",
        help="CommonRoad .xml files or folders of them",
    )
    q.add_argument("--out", required=True, help="output folder (resumable)")
    q.add_argument(
        "--methods",
        type=method_list(_ngsim_methods),
        default=["mmd", "degroot"],
        help="comma-separated planning methods, and 'reactive' (CommonRoad's reactive "
        "planner, a peer) (default: mmd,degroot)",
    )
    q.add_argument("--predictor", choices=PREDICTORS, default="learned")
    q.add_argument(
        "--holdout",
        nargs="+",
        default=None,
        metavar="PATTERN",
        help="plan only the held-out files of --scenarios (names or glob patterns); the split "
        "goes into run.json",
    )
    q.add_argument(
        "--config",
        type=existing_path,
        default=None,
        metavar="FILE.json",
        help="MMDOptConfig fields over the benchmark's defaults; a 'bench' sub-object sets "
        "NgsimParams (egos per time, range, samples, ...)",
    )
    q.add_argument(
        "--risk",
        type=float,
        default=None,
        metavar="EPS",
        help="plan in the risk mode at collision probability EPS in (0, 0.5): sample-driven "
        "margins, each method's mapping of EPS, the futures EPS needs drawn from the "
        "predictor, a risk column beside risk_bound (default: the preset's margins)",
    )
    add_executor(q)
    q.add_argument("--jobs", type=positive_int, default=1)
    q.add_argument("--max-tasks", type=positive_int, default=None, help="first N tasks only")
    q.add_argument(
        "--export",
        default=None,
        metavar="DIR",
        help="write each plan computed in this run as a CommonRoad solution file (KS model) to "
        "DIR (needs mmdopt[commonroad])",
    )
    return q


def _summary(rows: list[dict]) -> list[dict]:
    import numpy as np

    out = []
    keys = sorted({(r["method"], r["predictor"]) for r in rows})
    for m, p in keys:
        rr = [r for r in rows if r["method"] == m and r["predictor"] == p and "progress_m" in r]
        if not rr:
            continue
        prog = np.array([r["progress_m"] for r in rr])
        rec = np.array([r["recorded_progress_m"] for r in rr])
        out.append(
            dict(
                method=m,
                predictor=p,
                tasks=len(rr),
                at_fault=int(sum(bool(r["at_fault_collision"]) for r in rr)),
                any_collision=int(sum(bool(r["any_collision"]) for r in rr)),
                feasible=int(sum(bool(r["feasible"]) for r in rr)),
                progress_ratio=float(prog.sum() / max(rec.sum(), 1e-9)),
                collision_free_mean=float(np.mean([r["collision_free"] for r in rr])),
                plan_time_median_s=float(np.median([r["plan_time_s"] for r in rr])),
            )
        )
    return out


def _refuse(parser, option: str, reason) -> int:
    """``error: argument OPTION: reason`` and exit status 2 (argparse's form); without a parser
    the same line on stderr and 2 returned."""
    msg = f"argument {option}: {reason}" if option else str(reason)
    if parser is not None:
        parser.error(msg)
    print(f"mmdopt: error: {msg}", file=sys.stderr)
    return 2


def cmd_ngsim(args, parser=None) -> int:
    """``bench ngsim``: the scenario files, ``--config`` and ``--out`` are checked before
    anything is written (exit 2 naming the option); scenes that give no task at all are exit 2
    naming ``--scenarios`` with the reason (the task conditions and, per file, how many
    vehicles meet each)."""
    from .inputs import ScenarioError, load_ngsim_config
    from .runner import run_ngsim

    try:
        cfg, params = load_ngsim_config(args.config)
    except ValueError as e:
        return _refuse(parser, "--config", e)
    if getattr(args, "risk", None) is not None:
        from mmdopt.risk import check_risk

        try:
            check_risk(args.risk, "EPS")
        except ValueError as e:
            return _refuse(parser, "--risk", e)
    if args.export is not None:
        from .crcheck import available

        if available() is not None:
            return _refuse(parser, "--export", available())
    try:
        rows = run_ngsim(
            args.scenarios,
            args.out,
            methods=args.methods,
            predictor=args.predictor,
            config=cfg,
            params=params,
            executor=args.executor,
            jobs=args.jobs,
            max_tasks=args.max_tasks,
            address=args.address,
            progress=True,
            isolate=True,
            export=args.export,
            risk=getattr(args, "risk", None),
            holdout=args.holdout,
        )
    except ScenarioError as e:
        return _refuse(parser, "--scenarios", e)
    except ValueError as e:  # a folder of other settings, a damaged run.json, Ray missing
        if "holdout pattern" in str(e):
            return _refuse(parser, "--holdout", e)
        return _refuse(parser, "", e)
    refused = json.loads(Path(args.out, "refused.json").read_text())
    for name, why in refused.items():
        print(f"refused {name}: {why}")
    seen = json.loads(Path(args.out, "trained_on.json").read_text())
    if seen:
        print(
            f"note: the learned predictor was trained on {len(seen)} of these scenes "
            f"({', '.join(seen[:4])}{', …' if len(seen) > 4 else ''}); --holdout plans only "
            "held-out ones"
        )
    summ = _summary(rows)
    Path(args.out, "summary.json").write_text(json.dumps(summ, indent=1))
    for s in summ:
        print(json.dumps(s))
    from .crcheck import disagreements

    print(disagreements(rows))
    errors = [r for r in rows if str(r.get("status", "")).startswith("error")]
    if errors:
        print(f"{len(errors)} task(s) failed; see 'status' in {args.out}/results.csv")
    print(f"wrote {Path(args.out) / 'results.csv'} ({len(rows)} rows)")
    return 0


def add_train_parser(subparsers) -> argparse.ArgumentParser:
    """``predictor train`` and ``predictor eval`` (a ``predictor`` command with two actions)."""
    p = subparsers.add_parser("predictor", help="train / evaluate the learned predictor")
    ps = p.add_subparsers(dest="predictor_command", required=True, metavar="{train,eval}")
    t = ps.add_parser("train", help="train the MDN predictor on the training split")
    t.add_argument(
        "--data",
        nargs="+",
        type=existing_path,
        default=None,
        metavar="PATH",
        help="CommonRoad scenes (files or folders; default: the shared US-101 folder; the "
        "urban weights: it and the Lankershim folder)",
    )
    _add_holdout(t)
    t.add_argument(
        "--out",
        default=None,
        help="weights path without suffix (default: the package's shipped weights)",
    )
    t.add_argument("--steps", type=positive_int, default=2000)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--no-eval", action="store_true", help="skip the held-out evaluation")
    _add_source(t)
    t.add_argument(
        "--duration",
        type=positive_float,
        default=30.0,
        help="--source highway: simulated seconds per training rollout (default 30)",
    )
    e = ps.add_parser("eval", help="minADE/minFDE@20 and NLL of all predictors, held-out split")
    e.add_argument("--data", nargs="+", type=existing_path, default=None, metavar="PATH")
    _add_holdout(e)
    e.add_argument("--weights", default=None, help="learned weights (default: shipped)")
    e.add_argument("--out", default=None, help="write the table as JSON here")
    _add_source(e, eval_=True)
    return p


def _add_holdout(q: argparse.ArgumentParser) -> None:
    q.add_argument(
        "--holdout",
        nargs="+",
        default=None,
        metavar="PATTERN",
        help="the held-out files: names or glob patterns (default: US-101 recordings N %% 5 == 0, "
        "other scenes LOC-M_N_T-1 with N %% 5 == 0)",
    )


def _add_source(q: argparse.ArgumentParser, eval_: bool = False) -> None:
    q.add_argument(
        "--source",
        choices=("ngsim", "highway"),
        default="ngsim",
        help="ngsim: the US-101 scenes of --data (default); highway: highway-env rollouts "
        "(highway-v0 default and dense, merge-v0)",
    )
    q.add_argument(
        "--episodes",
        type=positive_int,
        default=10 if eval_ else 8,
        help="--source highway: rollouts per environment (merge-v0: 4x), seeds "
        + ("0, 1, ... (held out)" if eval_ else "100000, 100001, ...")
        + f" (default {10 if eval_ else 8})",
    )


def evaluate_heldout(
    data=None,
    weights=None,
    *,
    k: int = 20,
    n_nll: int = 200,
    seed: int = 1,
    stride: int = 20,
    holdout=None,
) -> list[dict]:
    """minADE/minFDE@k and KDE NLL of cv, lane and learned on the held-out files of ``data``
    (windows every ``stride`` steps = 2 s); where the held-out files have cars with more than
    one route (junctions), the rows of :func:`.routes.evaluate_routes` on them too."""
    import jax

    from mmdopt.predict import ConstantVelocity, LaneAware, evaluate_predictor
    from mmdopt.predict.learned import Learned

    from .data import split_files, windows
    from .routes import evaluate_routes

    _, test = split_files(default_training_data() if data is None else data, holdout)
    W = windows(test, stride=stride)
    preds = [ConstantVelocity(), LaneAware(), Learned(weights)]
    rows = [evaluate_predictor(p, W, jax.random.PRNGKey(seed), k=k, n_nll=n_nll) for p in preds]
    urban = [f for f in test if "US101" not in f.name]
    if urban:
        for r in evaluate_routes(urban, k=k, stride=5, seed=seed, weights_mdn=weights):
            rows.append(dict(r, split="held-out, urban"))
    return rows


def _checked_split(data, parser, need: str, holdout=None) -> tuple[list[Path], list[Path]]:
    """(train, held-out) files of ``--data`` / ``--holdout``, every file checked
    (:func:`~mmdopt.bench.ngsim.inputs.check_scenario_file`) and the split ``need``ed
    ("train" or "held-out") not empty; exit 2 naming the option otherwise."""
    from .data import split_files
    from .inputs import check_scenario_file

    try:
        train, test = split_files(data, holdout)
    except ValueError as e:
        _refuse(parser, "--holdout" if "holdout pattern" in str(e) else "--data", e)
        raise SystemExit(2) from None
    try:
        for f in train + test:
            check_scenario_file(f)
    except ValueError as e:
        _refuse(parser, "--data", e)
        raise SystemExit(2) from None
    split = train if need == "train" else test
    if not split:
        _refuse(
            parser,
            "--holdout" if holdout is not None else "--data",
            f"no {need} recordings among the {len(train) + len(test)} file(s) of --data "
            f"(held out: {len(test)}; --holdout names them)",
        )
        raise SystemExit(2)
    return train, test


def cmd_train(args, parser=None) -> int:
    """``predictor train``: ``--data`` (every file, the split, usable windows) and ``--out``
    are checked before the ~3 min of windows and the training (exit 2 naming the option)."""
    from mmdopt.predict.learned import DEFAULT_WEIGHTS, MDNConfig, save_weights
    from mmdopt.predict.train import fit_mdn

    from ..inputs import check_out_file
    from .data import TRAIN_WEIGHT_DECAY, describe_split, windows
    from .inputs import ScenarioError
    from .routes import fit_route_weights, save_route_weights

    data = default_data_dir() if args.data is None else args.data
    holdout = getattr(args, "holdout", None)
    train, test = _checked_split(data, parser, "train", holdout)
    out = DEFAULT_WEIGHTS if args.out is None else Path(args.out)
    try:
        check_out_file(f"{out}.eqx")
    except ValueError as e:
        return _refuse(parser, "--out", e)
    t0 = time.perf_counter()
    try:
        W = windows(train, stride=2)
    except ScenarioError as e:
        return _refuse(parser, "--data", e)
    if not W:
        return _refuse(
            parser,
            "--data",
            f"{data}: no usable training windows in {len(train)} file(s) (a window needs "
            "vehicles on the lane map recorded over 10 history rows and the 5 s horizon)",
        )
    print(
        f"{len(train)} training scenes ({len(test)} held out), {len(W)} windows "
        f"({time.perf_counter() - t0:.0f} s)",
        flush=True,
    )
    cfg = MDNConfig()
    pred, info = fit_mdn(W, cfg, steps=args.steps, seed=args.seed, weight_decay=TRAIN_WEIGHT_DECAY)
    paths = [data] if isinstance(data, str | Path) else list(data)
    command = (
        f"mmdopt predictor train --data {' '.join(map(str, paths))}"
        + (f" --out {args.out}" if args.out is not None else "")
        + f" --steps {args.steps} --seed {args.seed}"
        + (f" --holdout {' '.join(holdout)}" if holdout else "")
    )
    split = describe_split(train, test, holdout)
    info.update(split=split["holdout"], train_files=split["train_files"], command=command)
    info["heldout_files"] = split["heldout_files"]
    base = save_weights(out, pred.model, pred.config, pred.norm, info)
    print(
        f"wrote {base}.eqx / .json (final train NLL {info['final_nll']:.3f}, "
        f"{info['train_s']:.0f} s)"
    )
    try:
        rw = fit_route_weights(train)
    except ValueError as e:  # no junction in the training files: the shipped routes stay
        print(f"route weights not fitted: {e}")
    else:
        rpath = Path(f"{base}_routes.json")
        save_route_weights(rpath, rw, dict(split, command=command))
        print(
            f"wrote {rpath} ({rw.info['n_cars']} cars with several routes, train accuracy "
            f"{rw.info['train_accuracy']:.2f})"
        )
    if not args.no_eval:
        for r in evaluate_heldout(data, base, holdout=holdout):
            print(json.dumps(r))
    return 0


def cmd_eval(args, parser=None) -> int:
    data = default_training_data() if args.data is None else args.data
    _checked_split(data, parser, "held-out", args.holdout)
    _report_rows(evaluate_heldout(data, args.weights, holdout=args.holdout), args.out)
    return 0


def _report_rows(rows: list[dict], out) -> None:
    """``predictor eval``'s output: one JSON line per row, and the list to ``out`` if given."""
    for r in rows:
        print(json.dumps(r))
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(rows, indent=1))


def cmd_predictor(args, parser=None) -> int:
    if getattr(args, "source", "ngsim") == "highway":
        return _cmd_highway(args, parser)
    if args.predictor_command == "train":
        return cmd_train(args, parser)
    return cmd_eval(args, parser)


def _cmd_highway(args, parser=None) -> int:
    """``predictor train|eval --source highway`` (:mod:`mmdopt.bench.highway.training`)."""
    from ..highway.settings import highway_available

    if args.data is not None:
        return _refuse(parser, "--data", "applies to --source ngsim only")
    if not highway_available():
        return _refuse(parser, "--source", 'highway needs highway-env: pip install -e ".[highway]"')
    from ..highway import training

    if args.predictor_command == "eval":
        _report_rows(training.evaluate_heldout(args.weights, episodes=args.episodes), args.out)
        return 0
    from ..highway.predictors import HIGHWAY_WEIGHTS

    base, info = training.train_highway(
        HIGHWAY_WEIGHTS if args.out is None else args.out,
        episodes=args.episodes,
        duration=args.duration,
        steps=args.steps,
        seed=args.seed,
        evaluate=not args.no_eval,
    )
    print(f"wrote {base}.eqx / .json (final train NLL {info['final_nll']:.3f})")
    for r in info.get("heldout", []):
        print(json.dumps(r))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Standalone entry: ``bench ngsim ...`` or ``predictor train|eval ...``."""
    p = argparse.ArgumentParser(prog="mmdopt")
    sub = p.add_subparsers(dest="command", required=True)
    b = sub.add_parser("bench")
    bs = b.add_subparsers(dest="experiment", required=True)
    add_ngsim_parser(bs)
    add_train_parser(sub)
    args = p.parse_args(argv)
    if args.command == "bench":
        return cmd_ngsim(args, p)
    return cmd_predictor(args, p)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
