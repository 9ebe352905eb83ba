"""Checks of the recorded-traffic inputs: scenario files, the ``--config`` of ``bench ngsim``, and
why a set of scenes gives no task.

* :func:`check_scenario_file`: a CommonRoad scenario file is non-empty, well-formed XML with a
  ``<commonRoad>`` root, lanelets and dynamic obstacles (cheap: no CommonRoad objects are built);
  :func:`~mmdopt.bench.ngsim.scene.load_scenario` runs it first and turns every error of the
  CommonRoad reader into :class:`ScenarioError` too, so a bad file is one error naming the file
  and the reason, whichever command reads it;
* :func:`load_ngsim_config`: ``--config FILE.json`` of ``bench ngsim`` (planner fields over
  :meth:`mmdopt.MMDOptConfig.ngsim` and an optional ``"bench"`` object of
  :class:`~mmdopt.bench.ngsim.runner.NgsimParams` fields), ``ValueError`` naming the key;
* :func:`explain_no_tasks`: which task condition no vehicle of the scenes meets (with the
  thresholds), for a ``bench ngsim`` run that would otherwise write zero rows.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any
from xml.parsers import expat

__all__ = ["ScenarioError", "check_scenario_file", "load_ngsim_config", "explain_no_tasks"]


class ScenarioError(ValueError):
    """A scenario path that cannot be used; the message names the file (or folder) and why."""


def check_scenario_file(path: str | Path) -> None:
    """Raise :class:`ScenarioError` (``"<path>: <reason>"``) unless ``path`` is a readable,
    non-empty, well-formed XML file with a ``<commonRoad>`` root holding at least one
    ``<lanelet>`` and one ``<dynamicObstacle>``."""
    p = Path(path)

    def bad(reason: str) -> ScenarioError:
        return ScenarioError(f"{p}: {reason}")

    if not p.is_file():
        raise bad("does not exist or is not a file")
    seen: dict[str, bool] = {}
    root: list[str] = []

    def start(name, attrs):  # noqa: ARG001
        if not root:
            root.append(name)
        if name in ("lanelet", "dynamicObstacle"):
            seen[name] = True

    # expat without building a tree: every byte is parsed (a truncated file is found) at a
    # tenth of ElementTree's cost
    parser = expat.ParserCreate()
    parser.StartElementHandler = start
    try:
        if p.stat().st_size == 0:
            raise bad("is empty (0 bytes)")
        with open(p, "rb") as f:
            parser.ParseFile(f)
    except expat.ExpatError as e:
        raise bad(f"is not well-formed XML (truncated or not XML: {e})") from None
    except OSError as e:
        raise bad(f"cannot be read ({e})") from None
    if root[0] != "commonRoad":
        raise bad(f"is not a CommonRoad scenario (root element <{root[0]}>, not <commonRoad>)")
    if "lanelet" not in seen:
        raise bad("has no lanelets (the lane network the ego plans on)")
    if "dynamicObstacle" not in seen:
        raise bad("has no dynamic obstacles (no recorded vehicles)")


def load_ngsim_config(source: Any = None):
    """``(MMDOptConfig, NgsimParams)`` of ``bench ngsim --config``: ``source`` is ``None``
    (the defaults), a JSON file path or an already parsed dict.  Planner fields, nested or flat
    (:meth:`mmdopt.MMDOptConfig.from_dict`), apply over :meth:`mmdopt.MMDOptConfig.ngsim`; a
    ``"bench"`` object sets :class:`~mmdopt.bench.ngsim.runner.NgsimParams` fields.  Raises
    ``ValueError`` naming the file or the key."""
    import mmdopt

    from .runner import NgsimParams, ngsim_config

    if source is None:
        return ngsim_config(), NgsimParams()
    from ..inputs import read_json

    raw = read_json(source) if isinstance(source, str | Path) else source
    if not isinstance(raw, dict):
        raise ValueError(
            "the config must be a JSON object of planner fields (and an optional 'bench' object)"
        )
    d = dict(raw)
    bench = d.pop("bench", {})
    if not isinstance(bench, dict):
        raise ValueError(
            f"'bench' must be a JSON object of NgsimParams fields, got {type(bench).__name__}"
        )
    try:
        params = NgsimParams.from_dict(bench)
    except (TypeError, ValueError) as e:
        raise ValueError(f"'bench' section: {e}") from None
    return mmdopt.MMDOptConfig.from_dict(d, base=ngsim_config()), params


def explain_no_tasks(files, params, config) -> str:
    """Why :func:`~mmdopt.bench.ngsim.runner.select_tasks` finds no task in ``files``: the
    conditions a task's ego must meet (with ``params``' thresholds) and, per file, how many
    vehicles pass each of them in turn (over every planning time t0)."""
    import numpy as np

    from .scene import load_scenario, present

    p = params
    need = (
        f"a task needs, at a planning time t0 = {p.first_t0:g}, {p.first_t0 + p.every:g}, … s, "
        f"a vehicle recorded over its history ({p.history} rows before t0, NgsimParams.history) "
        f"and the {config.trajectory.horizon:g} s horizon after t0, on the lane map at t0, at "
        f"most {p.max_ego_length:g} m long (max_ego_length), with another vehicle within "
        f"{p.range_m:g} m (range_m)"
    )
    lines = []
    for f in files:
        sc = load_scenario(str(f))
        K = int(round(config.trajectory.horizon / sc.dt))
        recorded = f"{sc.num_steps * sc.dt:.1f} s recorded, {len(sc.ids)} vehicle(s)"
        passed = [set(), set(), set(), set()]  # recorded, on the map, length, neighbour
        n_t0 = 0
        t0 = p.first_t0
        while True:
            k = int(round(t0 / sc.dt))
            if k + K >= sc.num_steps:
                break
            if k - p.history + 1 >= 0:
                n_t0 += 1
                ok = present(sc, k - p.history + 1, k + K)
                passed[0] |= set(np.flatnonzero(ok))
                ok &= sc.lane_of[:, k] >= 0
                passed[1] |= set(np.flatnonzero(ok))
                ok &= sc.length <= p.max_ego_length
                passed[2] |= set(np.flatnonzero(ok))
                here = np.isfinite(sc.xy[:, k, 0]) & np.isfinite(sc.xy[:, max(k - 1, 0), 0])
                for v in np.flatnonzero(ok):
                    d = np.linalg.norm(sc.xy[:, k] - sc.xy[v, k], axis=-1)
                    if np.any(here & (d <= p.range_m) & (np.arange(len(d)) != v)):
                        passed[3].add(int(v))
            t0 += p.every
        if n_t0 == 0:
            lines.append(
                f"{Path(f).name}: {recorded}; too short for one planning time "
                f"(needs more than {p.first_t0 + config.trajectory.horizon:g} s)"
            )
        else:
            c = [len(x) for x in passed]
            lines.append(
                f"{Path(f).name}: {recorded}, {n_t0} planning time(s); vehicles recorded over "
                f"history and horizon: {c[0]}, of them on the lane map: {c[1]}, short enough: "
                f"{c[2]}, with a vehicle within range: {c[3]}"
            )
    shown = lines[:5] + ([f"… and {len(lines) - 5} more file(s)"] if len(lines) > 5 else [])
    return f"no task selected from {len(lines)} scenario file(s): {need}. " + "; ".join(shown)
