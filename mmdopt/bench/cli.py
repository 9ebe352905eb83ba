"""``mmdopt`` command line: the demo and the paper's experiments.

::

    mmdopt --version
    mmdopt demo [--out DIR]                               plan one built-in scene, table + PNG
    mmdopt bench synthetic   --scenes N --seed S --out DIR [--methods mmd,degroot,random,saa]
                             [--scene-params FILE.json] [--backend NAME] [--config FILE.json]
                             [--preset paper100|reference36|lanechange] [--jobs J]
    mmdopt bench frontier    --out DIR [--risks 'mmd=0.001,0.005;saa=0.02'] [--methods ...]
                             [--n-validation N] [--n-samples N]
                             (safety-progress frontier: every method's risk level swept)
    mmdopt bench reduced-set --scenes N --random-sets R --out DIR       (paper Fig. 4)
    mmdopt bench timing      --out DIR [--sizes 10,20,30,40,50] [--samples 50,100,200]
    mmdopt bench figure      --scene I --out DIR                        (paper Fig. 3)
    mmdopt bench qp-backends [ARGS...]                                  QP backend comparison
    mmdopt bench highway     --episodes N --seed S --duration T --out DIR   (closed loop)
    mmdopt bench ngsim --scenarios PATH [PATH ...] --out DIR            recorded US-101 traffic
    mmdopt predictor train|eval [--data DIR]                            the learned predictor

Bad options, files and folders exit with status 2 and a message naming the option (argparse),
before anything is written into ``--out`` (:mod:`.inputs`, :mod:`.ngsim.inputs`); so does
``bench ngsim`` on scenes that give no task (the message says which condition nobody meets).
An error prints the usage of the command it belongs to (``usage: mmdopt bench frontier ...``).
Every sweep plans in worker processes with one XLA thread, ``--jobs 1`` included, so its rows do
not depend on ``--jobs`` or ``--executor``.

Building the parser imports neither the method nor JAX, matplotlib or Ray: a command imports
what it runs, and the sub-commands defined in modules that import the method (``bench highway``,
``bench ngsim``, ``predictor``) get their parser when chosen (:class:`_LazySubParsers`), so
``--help`` and ``--version`` answer at once.  The names the help lists (the built-in methods,
the default risk grid, the presets, the planner's backend) are literals here, checked against
their sources by the tests.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

__all__ = ["main", "build_parser"]

from ._optional import MissingExtra, install_hint, missing_for
from .argtypes import (
    add_executor,
    existing_file,
    int_list,
    method_list,
    nonneg_int,
    positive_int,
)
from .executors import Interrupted, stop_on_signals

REDUCED_SET_METHODS = ("mmd", "herding", "degroot", "random")

#: the built-in planning methods, :data:`mmdopt.methods.PLAN_METHODS` (the default of ``bench
#: frontier --methods``), written out so that the parser need not import the method
PLAN_METHODS = ("mmd", "degroot", "random", "saa", "cvar", "scenario_all")
#: the planner's own projection backend, :data:`mmdopt.algorithm.PLANNER_BACKEND`
PLANNER_BACKEND = "admm-fixed"
#: the default risk grid of ``bench frontier``, :data:`mmdopt.bench.frontier.DEFAULT_RISK_GRID`
DEFAULT_RISK_GRID = (1e-5, 1e-4, 0.001, 0.005, 0.02, 0.1)
#: the scene presets, the names of :data:`mmdopt.bench.scenes.PRESETS` (sorted)
PRESETS = ("cutin-high", "cutin-low", "lanechange", "paper100", "reference36", "static-bimodal",
           "static-gaussian", "static-trimodal")  # fmt: skip


# ---------------------------------------------------------------------------------------------
# argument types


def _method_names() -> tuple[str, ...]:
    """The planning methods registered when ``--methods`` is parsed
    (:func:`mmdopt.methods.names`); imported only then."""
    import mmdopt.methods

    return tuple(mmdopt.methods.names())


def _backend(s: str) -> str:
    if s == PLANNER_BACKEND:
        return s
    avail = _backend_names()
    if s not in avail:
        raise argparse.ArgumentTypeError(
            f"backend {s!r} is not available; available: {', '.join(avail)}"
        )
    return s


def _backend_names() -> list[str]:
    """The planner's own backend and every QP backend installed (:func:`solvers.available_backends`,
    which imports NumPy and SciPy: only when a backend is named or the help is shown)."""
    import solvers

    return [PLANNER_BACKEND, *solvers.available_backends()]


class _DeprecatedRisks(argparse.Action):
    """``--knobs``, the old name of ``--risks``: stores the value there, warns on stderr."""

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"mmdopt: {option_string} is deprecated; use --risks (same values)", file=sys.stderr)
        setattr(namespace, self.dest, values)


class _HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter; an action with a ``help_more`` callable gets its text appended to
    its help line when the help is shown (the installed QP backends are looked up then, not
    when the parser is built or an error prints the usage)."""

    def _get_help_string(self, action):
        text = super()._get_help_string(action)
        more = getattr(action, "help_more", None)
        return text + more().replace("%", "%%") if more and text else text


class _LazySubParsers(argparse._SubParsersAction):
    """Sub-commands whose parser is built when one is chosen (:meth:`add_lazy`): until then a
    placeholder carries its name and one-line help for the listing of ``--help``.  ``bench
    highway``, ``bench ngsim`` and ``predictor`` are defined in modules that import the method
    (JAX): building them for every ``mmdopt --help`` would cost seconds."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._builders: dict[str, Callable[[argparse._SubParsersAction], object]] = {}

    def add_lazy(self, name: str, help: str, build: Callable[[_LazySubParsers], object]) -> None:
        """A placeholder for ``name``; ``build(self)`` adds the real parser (``add_parser``)."""
        self.add_parser(name, help=help, add_help=False)
        self._builders[name] = build

    def load(self, name: str) -> argparse.ArgumentParser:
        """The parser of ``name``, built now if it is a placeholder (in the placeholder's place
        of the listing)."""
        build = self._builders.pop(name, None)
        if build is not None:
            i, old = next((i, a) for i, a in enumerate(self._choices_actions) if a.dest == name)
            del self._choices_actions[i], self._name_parser_map[name]
            build(self)
            new = [a for a in self._choices_actions if a.dest == name]
            if new:
                self._choices_actions.remove(new[0])
            self._choices_actions.insert(i, new[0] if new else old)
        return self._name_parser_map[name]

    def load_all(self) -> None:
        """Build every placeholder's parser (e.g. to inspect the whole command line)."""
        for name in list(self._builders):
            self.load(name)

    def __call__(self, parser, namespace, values, option_string=None):
        if values and values[0] in self._builders:
            self.load(values[0])
        super().__call__(parser, namespace, values, option_string)


# ---------------------------------------------------------------------------------------------
# parser


def version() -> str:
    """The installed distribution's version (package metadata), else ``mmdopt.__version__``."""
    try:
        from importlib.metadata import PackageNotFoundError
        from importlib.metadata import version as _dist_version

        return _dist_version("mmdopt")
    except PackageNotFoundError:
        import mmdopt

        return mmdopt.__version__


def _add_backend(q: argparse.ArgumentParser, help: str = "projection QP backend") -> None:
    a = q.add_argument(
        "--backend",
        type=_backend,
        default=PLANNER_BACKEND,
        metavar="NAME",
        help=f"{help} (default: {PLANNER_BACKEND})",
    )
    a.help_more = lambda: f"; choices (installed): {', '.join(_backend_names())}"


def _add_methods(q: argparse.ArgumentParser, choices, default: list[str], help: str | None) -> None:
    q.add_argument("--methods", type=method_list(choices), default=default, help=help)


def _add_no_progress(q: argparse.ArgumentParser) -> None:
    q.add_argument("--no-progress", action="store_true", help="no progress bar")


def _obstacle_count(text: str) -> int:
    n = positive_int(text)
    if n > 5:
        raise argparse.ArgumentTypeError(f"must be 1 … 5, got {n}")
    return n


def _add_obstacles(q: argparse.ArgumentParser, default: int | None, text: str) -> None:
    q.add_argument("--obstacles", type=_obstacle_count, default=default, metavar="N", help=text)


def _add_sweep_options(q: argparse.ArgumentParser, scenes_default: int | None) -> None:
    """The options every scene sweep shares: scenes, seed, preset, scene parameters, backend,
    planner config, jobs, progress and executor; then its resumable ``--out``."""
    q.add_argument(
        "--scenes",
        type=positive_int,
        default=scenes_default,
        help="number of scenes (default: the preset's)",
    )
    q.add_argument("--seed", type=nonneg_int, default=0, help="sweep seed (default 0)")
    q.add_argument(
        "--preset",
        choices=PRESETS,
        default="paper100",
        help="scene preset (default paper100)",
    )
    q.add_argument(
        "--scene-params",
        type=existing_file,
        default=None,
        metavar="FILE.json",
        help="JSON object overriding scene-generator parameters (see README)",
    )
    _add_obstacles(q, None, "obstacles per scene, 1-5 (default: the preset's: 1 in the "
                   "paper's, 2 in the journal's families)")  # fmt: skip
    _add_backend(q)
    q.add_argument(
        "--config",
        type=existing_file,
        default=None,
        metavar="FILE.json",
        help="JSON object overriding MMDOptConfig fields, nested by section, e.g. "
        '{"cem": {"iterations": 10}} (see README)',
    )
    q.add_argument(
        "--jobs",
        type=positive_int,
        default=os.cpu_count() or 1,
        help="parallel worker processes (default: number of cores)",
    )
    _add_no_progress(q)
    add_executor(q)
    q.add_argument("--out", required=True, help="output folder (resumable)")


def _add_demo_parser(sub) -> None:
    d = sub.add_parser(
        "demo", help="plan one built-in multi-modal scene; print a table, write a PNG"
    )
    d.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    _add_methods(
        d,
        _method_names,
        ["mmd", "degroot"],
        "comma-separated planning methods (default: mmd,degroot)",
    )
    d.add_argument(
        "--risks",
        type=_risk_list,
        default=list(DEMO_RISKS),
        metavar="EPS,EPS,...",
        help="risk levels ε (target collision probability, each in (0, 0.5)) each method plans "
        f"at (default: {','.join(f'{r:g}' for r in DEMO_RISKS)})",
    )
    _add_obstacles(d, 1, "obstacles in the scene, 1-5 (default 1: the built-in scene; more add "
                   "cars of the same generator ahead)")  # fmt: skip
    _add_backend(d)


#: the demo's risk levels ε: with 0.0002 the two methods' safety ranges overlap on the demo scene
DEMO_RISKS = (0.02, 0.005, 0.001, 0.0002)


def _risk_list(s: str) -> list[float]:
    """``--risks``: comma-separated distinct ε in (0, 0.5)."""
    try:
        out = [float(x) for x in s.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected numbers separated by commas, got {s!r}"
        ) from None
    if not out:
        raise argparse.ArgumentTypeError("expected at least one risk level")
    bad = [x for x in out if not 0.0 < x < 0.5]
    if bad:
        raise argparse.ArgumentTypeError(f"each risk level must be in (0, 0.5), got {bad}")
    if len(set(out)) != len(out):
        raise argparse.ArgumentTypeError(f"risk levels repeat: {s!r}")
    return out


def _add_synthetic_parser(bs) -> None:
    s = bs.add_parser("synthetic", help="MMD-Opt vs baselines on synthetic scenes (paper Fig. 5)")
    _add_sweep_options(s, None)
    _add_methods(
        s,
        _method_names,
        ["mmd", "degroot", "random", "saa"],
        "comma-separated methods (default: mmd,degroot,random,saa)",
    )
    _add_n_samples(s)


def _add_receding_parser(bs) -> None:
    r = bs.add_parser(
        "receding", help="the journal's receding-horizon runs through a scene family's scenes"
    )
    r.add_argument("--preset", choices=PRESETS, default="cutin-high",
                   help="scene family (default cutin-high)")  # fmt: skip
    _add_obstacles(r, None, "obstacles per scene, 1-5 (default: the preset's)")
    r.add_argument("--scenes", type=positive_int, default=5, help="episodes (default 5)")
    r.add_argument("--seed", type=nonneg_int, default=0, help="sweep seed (default 0)")
    r.add_argument("--scene-params", type=existing_file, default=None, metavar="FILE.json",
                   help="JSON object overriding scene-generator parameters")  # fmt: skip
    _add_methods(r, _method_names, ["mmd", "cvar", "saa"],
                 "comma-separated methods (default: mmd,cvar,saa)")  # fmt: skip
    r.add_argument(
        "--risk",
        type=_risk_list,
        default=[0.005],
        metavar="EPS[,EPS...]",
        help="risk level(s) ε every replan is asked to keep (default 0.005)",
    )
    r.add_argument(
        "--replan-dt",
        type=_positive_float,
        default=0.5,
        metavar="S",
        help="seconds of each plan executed before replanning (default 0.5)",
    )
    r.add_argument(
        "--duration",
        type=_positive_float,
        default=10.0,
        metavar="S",
        help="episode length in seconds, at most 15 (default 10)",
    )
    r.add_argument(
        "--budget",
        type=_positive_float,
        default=0.1,
        metavar="S",
        help="per-replan plan-time budget reported against (default 0.1 s: 10 Hz)",
    )
    r.add_argument(
        "--config",
        type=existing_file,
        default=None,
        metavar="FILE.json",
        help="JSON object overriding MMDOptConfig fields, nested by section",
    )
    r.add_argument("--jobs", type=positive_int, default=os.cpu_count() or 1,
                   help="parallel worker processes (default: number of cores)")  # fmt: skip
    _add_no_progress(r)
    add_executor(r)
    r.add_argument("--out", required=True, help="output folder")


def _budget_list(text: str) -> list[float]:
    out = [_positive_float(x) for x in text.split(",") if x.strip()]
    if not out:
        raise argparse.ArgumentTypeError("give at least one budget, e.g. 0.1,0.25,1")
    return sorted(set(out))


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not (v > 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return v


def _add_n_samples(p) -> None:
    p.add_argument(
        "--n-samples",
        type=positive_int,
        default=None,
        metavar="N",
        help="plan on N fixed samples per obstacle (overrides --scene-params' n_samples); "
        "without it every plan draws n(ε) futures from the scene's predictor "
        "(mmdopt.risk.samples_for_risk, at least the preset's n_samples, at most 5000)",
    )


def _add_frontier_parser(bs) -> None:
    fr = bs.add_parser("frontier", help="safety-progress frontier: each method's risk level swept")
    _add_sweep_options(fr, None)
    _add_methods(
        fr,
        _method_names,
        list(PLAN_METHODS),
        f"comma-separated methods (default: the built-ins, {','.join(PLAN_METHODS)})",
    )
    fr.add_argument(
        "--risks",
        default=None,
        help="risk grids (target collision probability): '0.1,0.02,0.005' for every method or "
        "per method, e.g. 'mmd=0.001,0.005,0.02;saa=0.005,0.02' "
        f"(default: {','.join(f'{r:g}' for r in DEFAULT_RISK_GRID)} for every method)",
    )
    fr.add_argument("--knobs", dest="risks", action=_DeprecatedRisks, help=argparse.SUPPRESS)
    fr.add_argument(
        "--budgets",
        type=_budget_list,
        default=[0.1, 0.25, 1.0],
        metavar="S,S,...",
        help="plan-time budgets (s) of the matched-compute readout: progress at 990/995/999 "
        "using only the risk levels whose median plan_time_s is within each budget (default: "
        "0.1,0.25,1)",
    )
    fr.add_argument(
        "--n-validation",
        type=positive_int,
        default=None,
        metavar="N",
        help="validation futures per scene, the measure of the collision rate (default: the "
        "preset's, 1000; 10000 resolves ε = 1e-4); overrides --scene-params' n_validation",
    )
    _add_n_samples(fr)


def _add_reduced_set_parser(bs) -> None:
    r = bs.add_parser(
        "reduced-set", help="reduced-set selection vs random reduced sets and alternatives (Fig. 4)"
    )
    _add_sweep_options(r, 20)
    r.add_argument(
        "--random-sets",
        type=positive_int,
        default=20,
        help="random reduced sets per scene: the near-exhaustive search (default 20)",
    )
    _add_methods(
        r,
        REDUCED_SET_METHODS,
        list(REDUCED_SET_METHODS),
        "reduced-set selection methods (default: mmd,herding,degroot,random)",
    )


def _add_timing_parser(bs) -> None:
    t = bs.add_parser("timing", help="computation time vs reduced-set size and samples (Table II)")
    t.add_argument("--out", required=True, help="output folder")
    t.add_argument(
        "--sizes",
        type=int_list,
        default=[10, 20, 30, 40, 50],
        help="reduced-set sizes (default 10,20,30,40,50)",
    )
    t.add_argument(
        "--samples",
        type=int_list,
        default=[50, 100, 200],
        help="numbers of planning samples n (default 50,100,200)",
    )
    t.add_argument(
        "--repeats",
        type=positive_int,
        default=5,
        help="timed calls per setting; the median is reported (default 5)",
    )
    _add_backend(t)
    t.add_argument(
        "--obstacles",
        type=int_list,
        default=None,
        help="also time plan() against these numbers of obstacles, e.g. 1,5,10,20 "
        "(timing_obstacles.csv)",
    )
    _add_no_progress(t)


def _add_figure_parser(bs) -> None:
    f = bs.add_parser("figure", help="qualitative scene figure (paper Fig. 3)")
    f.add_argument(
        "--scene",
        type=nonneg_int,
        default=None,
        help="scene index in the preset (default: the built-in demo scene)",
    )
    f.add_argument("--seed", type=nonneg_int, default=0)
    f.add_argument("--preset", choices=PRESETS, default="reference36")
    f.add_argument("--scene-params", type=existing_file, default=None, metavar="FILE.json")
    _add_methods(f, _method_names, ["degroot", "mmd"], None)
    _add_backend(f)
    f.add_argument("--out", required=True, help="output folder")


def _add_qp_backends_parser(bs) -> None:
    q = bs.add_parser(
        "qp-backends", help="QP backend comparison (benchmarks/qp_backends.py)", add_help=False
    )
    q.add_argument("args", nargs=argparse.REMAINDER, help="arguments passed to the benchmark")


class _Parser(argparse.ArgumentParser):
    """argparse's parser with :class:`_HelpFormatter`; its sub-commands are parsers of this
    class too (argparse makes them of the parent's class)."""

    def __init__(self, *args, formatter_class=_HelpFormatter, **kwargs):
        super().__init__(*args, formatter_class=formatter_class, **kwargs)


#: one-line help of the sub-commands built when chosen (a test checks it is their modules')
LAZY_HELP = {
    "highway": "closed-loop receding-horizon driving in highway-env",
    "ngsim": "plan as a recorded car in recorded US-101 traffic (CommonRoad scenes)",
    "predictor": "train / evaluate the learned predictor",
}


def _add_highway(bs) -> None:
    from .highway.cli import add_highway_parser

    add_highway_parser(bs)


def _add_ngsim(bs) -> None:
    from .ngsim.cli import add_ngsim_parser

    add_ngsim_parser(bs)


def _add_predictor(sub) -> None:
    from .ngsim.cli import add_train_parser

    add_train_parser(sub)


#: where the CLI keeps JAX's compiled programs (``--no-compile-cache``), as its help says it
COMPILE_CACHE_HELP = "$XDG_CACHE_HOME/mmdopt/jax (default ~/.cache/mmdopt/jax)"


def compile_cache_dir(env: Mapping[str, str] | None = None) -> Path | None:
    """The folder of the CLI's persistent JAX compilation cache
    (:func:`mmdopt.compile_cache.compile_cache_dir`)."""
    from mmdopt.compile_cache import compile_cache_dir as folder

    return folder(env)


def enable_compile_cache(args) -> Path | None:
    """Turn on JAX's persistent compilation cache for this run
    (:func:`mmdopt.enable_compile_cache`) unless ``--no-compile-cache`` or
    ``MMDOPT_COMPILE_CACHE=0``: a first plan in a new process then loads Algorithm 1's programs
    instead of compiling them.  Returns the folder, or ``None``."""
    if getattr(args, "no_compile_cache", False):
        return None
    from mmdopt.compile_cache import enable_compile_cache as enable

    return enable()


def build_parser() -> argparse.ArgumentParser:
    """The ``mmdopt`` argument parser: ``demo``, ``bench <experiment>`` and ``predictor``.

    Imports nothing of the method: ``bench highway``, ``bench ngsim`` and ``predictor`` are
    placeholders until chosen (:class:`_LazySubParsers`; :func:`load_all_parsers` builds them)."""
    p = _Parser(
        prog="mmdopt",
        description="MMD-Opt: planning under multi-modal obstacle predictions - demo and "
        "the paper's experiments.",
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    p.add_argument(
        "--no-compile-cache",
        action="store_true",
        help="do not keep JAX's compiled programs between runs (by default they are kept in "
        f"{COMPILE_CACHE_HELP}, so a second run's first plan does not compile again; "
        "MMDOPT_COMPILE_CACHE=0 does the same, MMDOPT_COMPILE_CACHE=DIR moves it)",
    )
    sub = p.add_subparsers(
        dest="command", required=True, metavar="{demo,bench,predictor}", action=_LazySubParsers
    )
    _add_demo_parser(sub)
    b = sub.add_parser("bench", help="the paper's experiments")
    bs = b.add_subparsers(
        dest="experiment",
        required=True,
        metavar="{synthetic,frontier,reduced-set,timing,figure,qp-backends,receding,highway,ngsim}",
        action=_LazySubParsers,
    )
    for add in (
        _add_synthetic_parser,
        _add_frontier_parser,
        _add_receding_parser,
        _add_reduced_set_parser,
        _add_timing_parser,
        _add_figure_parser,
        _add_qp_backends_parser,
    ):
        add(bs)
    bs.add_lazy("highway", LAZY_HELP["highway"], _add_highway)
    bs.add_lazy("ngsim", LAZY_HELP["ngsim"], _add_ngsim)
    sub.add_lazy("predictor", LAZY_HELP["predictor"], _add_predictor)
    return p


def _subparsers(p: argparse.ArgumentParser) -> argparse._SubParsersAction | None:
    """``p``'s sub-command action, if it has one."""
    return next((a for a in p._actions if isinstance(a, argparse._SubParsersAction)), None)


def load_all_parsers(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``parser`` (of :func:`build_parser`) with every placeholder sub-command built: the whole
    command line, e.g. to list every option (imports the method)."""
    sub = _subparsers(parser)
    if sub is not None:
        if isinstance(sub, _LazySubParsers):
            sub.load_all()
        for q in set(sub.choices.values()):
            load_all_parsers(q)
    return parser


def command_parser(parser: argparse.ArgumentParser, args) -> argparse.ArgumentParser:
    """The parser of the sub-command that ``args`` (parsed by ``parser``) names, e.g. that of
    ``mmdopt bench frontier`` or ``mmdopt predictor train``: its ``error`` prints that command's
    usage (exit status 2)."""
    p = parser
    while (sub := _subparsers(p)) is not None:
        name = getattr(args, sub.dest, None)
        if name not in sub.choices:
            break
        p = sub.choices[name]
    return p


# ---------------------------------------------------------------------------------------------
# helpers


def _scene_params(args, parser):
    from .scenes import load_scene_params, preset

    try:
        base = preset(args.preset)
        if args.scene_params is not None:
            base = load_scene_params(args.scene_params, base)
    except ValueError as e:
        parser.error(f"argument --scene-params: {e}")
    # options that override single scene parameters (``bench frontier``, ``--obstacles``)
    if getattr(args, "obstacles", None) is not None:
        try:
            base = base.replace(num_obstacles=args.obstacles)
        except ValueError as e:
            parser.error(f"argument --obstacles: {e}")
    for key in ("n_validation", "n_samples"):
        value = getattr(args, key, None)
        if value is not None:
            try:
                base = base.replace(**{key: value})
            except ValueError as e:
                parser.error(f"argument --{key.replace('_', '-')}: {e}")
    return base


def _planner_config(args, parser):
    """``MMDOptConfig`` with the overrides of ``--config FILE.json`` (``None`` without it)."""
    path = getattr(args, "config", None)
    if path is None:
        return None
    try:
        return load_planner_config(path)
    except ValueError as e:
        parser.error(f"argument --config: {e}")


def _checked_config(args, parser, methods):
    """``--config`` parsed and checked against the scenes and methods (the planning problem is
    built once) before anything is written into ``--out``; errors name the option."""
    from .synthetic import check_sweep_config

    params = _scene_params(args, parser)
    config = _planner_config(args, parser)
    try:
        check_sweep_config(params, config, methods, args.backend, args.seed)
    except ValueError as e:
        opt = "--config" if args.config is not None else "--scene-params"
        if args.config is not None and args.scene_params is not None:
            opt = "--config/--scene-params"
        parser.error(f"argument {opt}: {e}")
    return params, config


def load_planner_config(path):
    """The planner's config from a JSON file: the nested form of
    :meth:`mmdopt.MMDOptConfig.from_dict` (``{"cem": {"iterations": 10}, "safety": {"risk":
    0.001}}``) or flat field names (``{"iterations": 10}``).  Unknown keys, wrong types,
    NaN/Infinity or invalid values raise ``ValueError`` naming the key."""
    from .inputs import read_json

    return load_planner_config_from_dict(read_json(path))


def load_planner_config_from_dict(raw):
    """:func:`load_planner_config` from an already parsed JSON value
    (:meth:`mmdopt.MMDOptConfig.from_dict`: nested sections, or flat field names)."""
    from mmdopt.config import MMDOptConfig

    return MMDOptConfig.from_dict(raw)


def _table(rows: Sequence[dict], cols: Sequence[str], headers: dict[str, str] | None = None) -> str:
    """A right-aligned text table of ``rows``; ``headers`` maps a column key to its printed
    header (with its unit)."""
    headers = headers or {}

    def fmt(v):
        if isinstance(v, float):
            return f"{v:.3g}" if abs(v) < 100 else f"{v:.1f}"
        return str(v)

    cells = [[fmt(r.get(c, "")) for c in cols] for r in rows]
    names = [headers.get(c, c) for c in cols]
    w = [max(len(c), *(len(x[i]) for x in cells)) for i, c in enumerate(names)]
    line = lambda xs: "  ".join(x.rjust(w[i]) for i, x in enumerate(xs))  # noqa: E731
    return "\n".join([line(names), line(["-" * n for n in w])] + [line(x) for x in cells])


def _print_summary(summary: dict, n_validation: int | str = "N") -> None:
    """The per-method table of a synthetic sweep (collision-free counts of ``n_validation``
    validation samples per scene, over scenes)."""
    rows = []
    for m, s in summary["methods"].items():
        cf = s["collision_free"]
        v = summary["vs"].get(m, {})
        rows.append(
            dict(
                method=m,
                scenes=s["scenes"],
                mean=cf["mean"],
                std=cf["std"],
                q1=cf["q1"],
                median=cf["median"],
                min=cf["min"],
                progress_m=s["progress_m"]["mean"],
                feasible=s["feasible_share"],
                mmd_ge=v.get("share_ge", ""),
                plan_s=s["plan_time_s"]["median"],
            )
        )
    of = f"of {n_validation}"
    headers = {
        "mean": f"collision-free ({of}): mean",
        "q1": "Q1",
        "progress_m": "progress (m)",
        "feasible": "feasible (share)",
        "mmd_ge": "mmd >= it (share)",
        "plan_s": "plan time (s)",
    }
    cols = ["method", "scenes", "mean", "std", "q1", "median", "min"]
    cols += ["progress_m", "feasible", "mmd_ge", "plan_s"]
    print(_table(rows, cols, headers))


#: printed headers (with units) of the demo table and the timing table
DEMO_HEADERS = {
    "risk": "risk ε",
    "risk_bound": "risk bound",
    "progress_m": "progress (m)",
    "mean_speed": "mean speed (m/s)",
    "plan_s": "plan_s (s)",
    "compile_s": "compile_s (s)",
}
TIMING_HEADERS = {
    "reduced_set_size": "reduced-set size m",
    "n_samples": "samples n",
    "reduced_set_s": "reduced-set time (s)",
    "algorithm1_s": "Algorithm 1 time (s)",
    "plan_s": "plan time (s)",
    "compile_s": "compile time (s)",
}
#: printed headers of the frontier's first table (its collision-free counts are per 1000)
FRONTIER_HEADERS = {
    "mean": "collision-free per 1000: mean",
    "q1": "Q1 per 1000",
    "min": "min per 1000",
    "progress_m": "progress_m (m)",
    "plan_time_s": "plan_time_s (s)",
}
REDUCED_SET_HEADERS = {
    "mean_pct": "collision-free mean (%)",
    "std_pct": "std (%)",
    "progress_m": "progress (m)",
    "rs_mmd2": "reduced-set MMD²",
}


# ---------------------------------------------------------------------------------------------
# commands


def _matched(rows: Sequence[dict], methods: Sequence[str]) -> str:
    """One line comparing the methods at matched safety: the safest collision-free level every
    method reaches, and each method's best progress at or above it."""
    best = {m: max((r["collision_free"] for r in rows if r["method"] == m), default=None)
            for m in methods}  # fmt: skip
    if len(best) < 2 or None in best.values():
        return ""
    level = min(best.values())
    prog = {
        m: max(r["progress_m"] for r in rows if r["method"] == m and r["collision_free"] >= level)
        for m in methods
    }
    nv = rows[0]["n_validation"]
    return (
        f"at matched safety (≥ {level} of {nv} collision-free, the safest level every method "
        "reaches): " + ", ".join(f"{m} {v:.1f} m" for m, v in prog.items())
    )


def cmd_demo(args, parser) -> int:
    import mmdopt

    from . import plots
    from .metric import evaluate_plan
    from .scenes import demo_scene
    from .synthetic import scene_config

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    scene = demo_scene(args.obstacles)
    risks = list(args.risks)
    lay = scene.layout
    cars = "; ".join(
        f"a car at x0 = {x:.0f} m, y0 = {y:.1f} m ends in the ego lane with P = {pr[0]:.2f}"
        for x, y, pr in zip(lay.x0, lay.y0, scene.obstacle_intent_probs, strict=True)
    )
    print(
        f"scene: {cars}, else in the left lane; {scene.obstacles.shape[1]} planning samples, "
        f"{scene.validation.shape[1]} validation samples"
    )
    print(
        f"planning with {', '.join(args.methods)} at risk levels ε = "
        f"{', '.join(f'{r:g}' for r in risks)}; each method's first plan compiles Algorithm 1 "
        "(JAX, ~20-40 s on a CPU, once per process)…",
        flush=True,
    )
    cfg = scene_config(scene)
    ego, road = scene.ego(), scene.road()
    shown = 0.005 if 0.005 in risks else risks[len(risks) // 2]
    rows, plans = [], {}

    def plan(m, r, key):
        return mmdopt.plan(
            ego,
            road,
            scene.obstacles,
            method=m,
            config=cfg,
            projector=args.backend,
            key=key,
            risk=r,
        )

    for m in args.methods:
        # compile: the whole sweep once (the first plan compiles Algorithm 1; a plan whose
        # passes go deeper, which depends on its futures, compiles those passes' shapes), then
        # the same plans again, timed: compile_s is what the first sweep took beyond the second
        first_s = sum(float(plan(m, r, scene.key()).plan_time_s) for r in risks)
        mrows = []
        for r in risks:
            plan_ = plan(m, r, scene.key())
            row = evaluate_plan(plan_, scene, road)
            row.update(method=m, risk=r, plan_s=float(plan_.plan_time_s), backend=args.backend,
                       status=str(plan_.status), status_text=str(plan_.status_text))  # fmt: skip
            mrows.append(row)
            if r == shown:
                plans[m] = plan_
        compile_s = max(0.0, first_s - sum(row["plan_s"] for row in mrows))
        for row in mrows:
            row["compile_s"] = compile_s
        rows += mrows
    nv = rows[0]["n_validation"] if rows else "N"
    cols = ["method", "risk", "status", "risk_bound", "collision_free", "progress_m", "mean_speed",
            "feasible"]  # fmt: skip
    headers = dict(DEMO_HEADERS, collision_free=f"collision-free of {nv}")
    print(_table(rows, [*cols, "plan_s", "compile_s"], headers))
    print(
        "How to read it: a lower ε is a safer plan that drives less far, so compare methods at "
        "matched safety (progress at equal collision-free counts) or at matched progress, not "
        "row by row; compile_s is the one-off JIT compile (what the first run of the sweep "
        "took beyond the second), plan_s the plan itself. "
        "status says whether the plan keeps its ε: risk bound is the 95 % upper bound on its "
        "collision probability that the planning futures prove, and 'risk floor' means those "
        "futures are too few to prove ε (a predictor, the Forecast path, draws as many as ε "
        "needs)."
    )
    line = _matched(rows, list(args.methods))
    if line:
        print(line)
    png = plots.demo_figure(scene, plans, rows, out / "demo.png", risk=shown)
    with open(out / "demo.json", "w") as f:
        json.dump(rows, f, indent=1, default=str)
    print(f"wrote {png} and {out / 'demo.json'} in {time.perf_counter() - t0:.1f} s")
    return 0


def _receding_task(task):
    """One episode (a module-level function: the executors pickle it)."""
    from .loop import run_episode
    from .scenes import make_scene

    params, config, index, seed, method, risk, kw = task
    row = run_episode(make_scene(index, seed, params), method, risk, config=config, **kw)
    return row


def cmd_receding(args, parser) -> int:
    from .executors import WithMethods, run_tasks
    from .loop import LOOP_COLUMNS, summarise_episodes
    from .results import write_json, write_results

    params = _scene_params(args, parser)
    config = _planner_config(args, parser)
    if args.duration > 15.0:
        parser.error("argument --duration: at most 15 s (the scenes' horizon)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    kw = dict(dt=args.replan_dt, duration_s=args.duration, budget_s=args.budget)
    tasks = [(params, config, i, args.seed, m, r, kw)
             for m in args.methods for r in args.risk for i in range(args.scenes)]  # fmt: skip
    t0 = time.perf_counter()
    rows = run_tasks(
        WithMethods.wrap(_receding_task), tasks, jobs=args.jobs, executor=args.executor,
        address=args.address, progress=not args.no_progress, desc="episodes", unit="episode",
        isolate=True,
    )  # fmt: skip
    for r in rows:
        r["preset"] = args.preset
    rows.sort(key=lambda r: (list(args.methods).index(r["method"]), -r["risk"], r["scene"]))
    write_results(rows, out / "receding.csv", LOOP_COLUMNS)
    summary = summarise_episodes(rows)
    write_json(out / "receding_summary.json", dict(preset=args.preset, seed=args.seed,
               obstacles=params.num_obstacles, summary=summary))  # fmt: skip
    print(_table(summary, ["method", "risk", "episodes", "crashes", "progress_m", "mean_speed",
                           "median_plan_s", "ok_share"]))  # fmt: skip
    print(f"{len(rows)} episodes in {time.perf_counter() - t0:.1f} s; wrote "
          f"{out / 'receding.csv'}, {out / 'receding_summary.json'}")  # fmt: skip
    return 0


def cmd_synthetic(args, parser) -> int:
    from . import plots
    from .synthetic import run_synthetic

    params, config = _checked_config(args, parser, args.methods)
    try:
        res = run_synthetic(
            args.out,
            config=config,
            scenes=args.scenes,
            seed=args.seed,
            params=params,
            methods=args.methods,
            backend=args.backend,
            jobs=args.jobs,
            progress=not args.no_progress,
            executor=args.executor,
            address=args.address,
            isolate=True,
            forecast=args.n_samples is None,
        )
    except ValueError as e:
        parser.error(str(e))
    out = Path(args.out)
    plots.collision_box_violin(
        res["rows"],
        out / "collision_free.png",
        args.methods,
        title=f"{len(res['rows']) // len(args.methods)} scenes, "
        f"preset {args.preset}, seed {args.seed}",
    )
    nvs = sorted({r["n_validation"] for r in res["rows"]})
    _print_summary(res["summary"], nvs[0] if len(nvs) == 1 else "N")
    print(
        f"{res['computed']} plans computed, {res['reused']} reused, "
        f"{res['wall_s']:.1f} s; wrote {out / 'results.csv'}, {out / 'summary.json'}, "
        f"{out / 'collision_free.png'}"
    )
    return 0


def cmd_frontier(args, parser) -> int:
    from .frontier import KEPT_SHARE, TARGET_LEVELS, parse_risks, run_frontier

    try:
        risks = parse_risks(args.risks, args.methods)
    except ValueError as e:
        parser.error(f"argument --risks: {e}")
    params, config = _checked_config(args, parser, args.methods)
    try:
        res = run_frontier(
            args.out,
            risks=risks,
            methods=args.methods,
            config=config,
            scenes=args.scenes,
            seed=args.seed,
            params=params,
            backend=args.backend,
            jobs=args.jobs,
            progress=not args.no_progress,
            executor=args.executor,
            address=args.address,
            isolate=True,
            forecast=args.n_samples is None,
            budgets=args.budgets,
        )
    except ValueError as e:
        parser.error(str(e))
    cols = ["method", "risk", "scenes", "mean", "q1", "min", "progress_m", "plan_time_s",
            "n_planning"]  # fmt: skip
    print(
        "collision-free validation futures per 1000 (each scene's count scaled to 1000) over "
        "the scenes: mean, lower quartile, min; mean progress; median plan time (s, without the "
        "JIT compile: compile_s in frontier.csv)"
    )
    print(_table(res["points"], cols, FRONTIER_HEADERS))
    print(
        "measured collision rate (pooled over scenes, with its 95 % Clopper-Pearson interval), "
        "share of plans with status ok, mean risk_bound"
    )
    cols = ["method", "risk", "collisions", "validation", "rate", "rate_lo", "rate_hi",
            "ok_share", "risk_bound"]  # fmt: skip
    print(_table(res["points"], cols))
    lv = [f"{x:g}" for x in TARGET_LEVELS]
    readouts = (
        ("interpolated", "interpolated mean progress (m) at mean collision-free level (per "
         "1000); nan: not reached"),
        ("at_level", "most mean progress (m) of a risk level whose mean collision-free count "
         "reaches the level (measured points only); nan: not reached"),
        ("at_level_kept", "the same over the risk levels whose plans kept the request (status ok "
         f"in at least {KEPT_SHARE:.0%} of the scenes: risk_bound <= risk); nan: not reached"),
    )  # fmt: skip
    for key, title in readouts:
        print(title)
        rows = [{"method": m, **{f"progress_m@{k}": v[k] for k in lv}} for m, v in res[key].items()]
        print(_table(rows, ["method", *[f"progress_m@{k}" for k in lv]]))
    print("matched compute: the same (measured points) over the risk levels whose median "
          "plan_time_s is within each budget; nan: not reached within it")  # fmt: skip
    rows = [{"budget_s": b, "method": m, **{f"progress_m@{k}": v[k] for k in lv}}
            for b, per in res["at_budget"].items() for m, v in per.items()]  # fmt: skip
    print(_table(rows, ["budget_s", "method", *[f"progress_m@{k}" for k in lv]]))
    out = Path(args.out)
    print(
        f"{res['computed']} plans computed, {res['reused']} reused, {res['wall_s']:.1f} s; wrote "
        f"{out / 'frontier.csv'}, {out / 'frontier_summary.json'}, {out / 'frontier.png'}"
    )
    return 0


def cmd_reduced_set(args, parser) -> int:
    from .reduced_set import run_reduced_set

    params, config = _checked_config(args, parser, ["mmd"])
    try:
        res = run_reduced_set(
            args.out,
            config=config,
            scenes=args.scenes,
            seed=args.seed,
            params=params,
            methods=args.methods,
            random_sets=args.random_sets,
            backend=args.backend,
            jobs=args.jobs,
            progress=not args.no_progress,
            executor=args.executor,
            address=args.address,
            isolate=True,
        )
    except ValueError as e:
        parser.error(str(e))
    nv = res["rows"][0]["n_validation"] if res["rows"] else "N"
    headers = dict(REDUCED_SET_HEADERS, min=f"min (of {nv})")
    print(_table(res["table"], list(res["table"][0]), headers))
    print(f"wrote {Path(args.out) / 'reduced_set.csv'}, reduced_set_summary.json, reduced_set.png")
    return 0


def cmd_timing(args, parser) -> int:
    from .timing import run_timing

    low = [n for n in args.samples if n < min(args.sizes)]
    if low:
        parser.error(
            f"argument --samples: {','.join(map(str, low))} below the smallest reduced-set size "
            f"{min(args.sizes)} (--sizes): the sample sweep runs at the smallest size, which "
            "needs n >= m"
        )
    big = [m for m in args.sizes if m > 100]
    if big:
        parser.error(
            f"argument --sizes: {','.join(map(str, big))} above 100, the number of samples the "
            "size sweep uses"
        )
    res = run_timing(
        args.out,
        sizes=args.sizes,
        samples=args.samples,
        repeats=args.repeats,
        backend=args.backend,
        progress=not args.no_progress,
    )
    print(
        _table(
            res,
            [
                "reduced_set_size",
                "n_samples",
                "reduced_set_s",
                "algorithm1_s",
                "plan_s",
                "compile_s",
                "backend",
            ],
            TIMING_HEADERS,
        )
    )
    print(f"wrote {Path(args.out) / 'timing.csv'} and timing.png")
    if args.obstacles:
        from .timing import OBSTACLE_TIMING_COLUMNS, run_obstacle_timing

        rows = run_obstacle_timing(
            args.out,
            counts=args.obstacles,
            repeats=args.repeats,
            backend=args.backend,
            progress=not args.no_progress,
        )
        print(_table(rows, list(OBSTACLE_TIMING_COLUMNS)))
        print(f"wrote {Path(args.out) / 'timing_obstacles.csv'}")
    return 0


def cmd_figure(args, parser) -> int:
    from . import plots
    from .scenes import demo_scene, make_scene, num_scenes
    from .synthetic import run_scene

    params = _scene_params(args, parser)
    if args.scene is None and args.scene_params is None and args.preset == "reference36":
        scene = demo_scene()
    else:
        idx = args.scene or 0
        try:
            if idx >= num_scenes(params, max(idx + 1, 1)):
                raise ValueError(f"scene {idx} is outside the preset")
            scene = make_scene(idx, args.seed, params)
        except ValueError as e:
            parser.error(f"argument --scene: {e}")
    plans = {m: run_scene(scene, m, backend=args.backend)[1] for m in args.methods}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    png = plots.scene_figure(scene, plans, out / f"scene_{scene.index:04d}.png")
    print(f"wrote {png}")
    return 0


def cmd_qp_backends(args, parser) -> int:
    from . import qp_backends

    rest = [a for a in args.args if a != "--"]
    return int(qp_backends.main(rest) or 0)


def _check_out(args, parser) -> None:
    """``--out`` must be a folder, or a path where one can be created, that this process can
    write into (``predictor``: a file); ``--address`` needs ``--executor ray`` and a cluster
    that answers there.  Exit 2 naming the option otherwise (:mod:`.inputs`).  Nothing is
    created here."""
    from .inputs import check_address, check_out_file, check_out_folder

    out = getattr(args, "out", None)
    try:
        if args.command == "predictor":
            if out is not None:  # train: weights base path; eval: a JSON file
                train = args.predictor_command == "train"
                check_out_file(f"{out}.eqx" if train else out)
        elif out is not None:
            check_out_folder(out)
    except ValueError as e:
        parser.error(f"argument --out: {e}")
    if hasattr(args, "address"):
        from .executors import check_ray_address

        try:
            check_address(args.executor, args.address)
            if args.address is not None:
                check_ray_address(args.address)
        except ValueError as e:
            parser.error(f"argument --address: {e}")


def _cmd_ngsim(args, parser) -> int:
    from .ngsim.cli import cmd_ngsim

    return cmd_ngsim(args, parser)


def _needs(args) -> list[str]:
    """The optional modules (:mod:`._optional`) that the parsed command imports: matplotlib for
    its figures, tqdm for its progress bar (none with ``--no-progress``)."""
    what = args.experiment if args.command == "bench" else args.command
    figures = what in ("demo", "synthetic", "frontier", "reduced-set", "timing", "figure")
    bar = what in ("synthetic", "frontier", "reduced-set", "timing", "highway", "ngsim")
    bar = bar and not getattr(args, "no_progress", False)
    return [m for m, need in (("matplotlib", figures), ("tqdm", bar)) if need]


def _missing_extra(args) -> str | None:
    """One line naming the missing optional module and its extra, else ``None``."""
    missing = missing_for(_needs(args))
    if not missing:
        return None
    words = [args.command] + ([args.experiment] if args.command == "bench" else [])
    what = "mmdopt " + " ".join(words)
    hints = sorted({install_hint(m) for m in missing})
    return f"{what} needs {' and '.join(missing)} (not installed): {'; '.join(hints)}"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mmdopt`` console script; returns the exit status.

    The command runs with the parser of its sub-command (:func:`command_parser`): its errors
    print that command's usage.  SIGINT and SIGTERM stop a run cleanly: every worker is
    terminated, finished result files are kept (writes are atomic), one line goes to stderr and
    the status is 130 / 143."""
    parser = build_parser()
    # ``bench qp-backends`` passes its arguments on, options first included (``--help``):
    # argparse's REMAINDER does not take an argument list that starts with an option
    args, extra = parser.parse_known_args(argv)
    own = command_parser(parser, args)
    enable_compile_cache(args)
    if extra:
        if getattr(args, "experiment", None) != "qp-backends":
            own.error(f"unrecognized arguments: {' '.join(extra)}")
        args.args = extra + list(args.args)
    if args.command == "demo":
        cmd = cmd_demo
    elif args.command == "predictor":
        from .ngsim.cli import cmd_predictor

        def cmd(a, p):
            return cmd_predictor(a, p)
    else:
        cmd = {
            "synthetic": cmd_synthetic,
            "frontier": cmd_frontier,
            "receding": cmd_receding,
            "reduced-set": cmd_reduced_set,
            "timing": cmd_timing,
            "figure": cmd_figure,
            "qp-backends": cmd_qp_backends,
            "highway": lambda a, p: a.func(a, p),
            "ngsim": _cmd_ngsim,
        }[args.experiment]
    msg = _missing_extra(args)
    if msg:
        print(msg, file=sys.stderr)
        return 2
    try:
        with stop_on_signals():
            _check_out(args, own)
            return cmd(args, own)
    except MissingExtra as e:
        print(f"mmdopt: {e}", file=sys.stderr)
        return 2
    except Interrupted as e:
        where = getattr(args, "out", None)
        kept = f"; finished results are kept in {where} (run the same command to resume)"
        print(f"mmdopt: stopped by {e.name}{kept if where else ''}", file=sys.stderr)
        return e.exit_status


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
