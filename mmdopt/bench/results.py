"""Result files and summaries: ``results.csv`` rows, JSON records, per-method statistics."""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "RESULT_COLUMNS",
    "BARS",
    "write_json",
    "write_results",
    "remove_temp_files",
    "read_results",
    "summarize",
    "check_bars",
    "RESULT_TABLES",
    "load_results",
]

#: Columns of ``results.csv`` (the first seven are the outside contract).
RESULT_COLUMNS = (
    "scene",
    "method",
    "collision_free",
    "n_validation",
    "progress_m",
    "feasible",
    "plan_time_s",
    "collision_free_planning",
    "n_samples",
    "mean_speed",
    "final_speed",
    "kinematic_violation",
    "planner_feasible",
    "fallback",
    "status",
    "cost",
    "mmd",
    "residual",
    "wall_s",
    "x0",
    "y0",
    "p",
    "seed",
    "backend",
    "risk_bound",
)

#: Bars for MMD-Opt on 100 scenes × 1000 validation samples: the paper's mean and lower quartile
#: (§IV-C, Fig. 5); at least de Groot's collision-free count in 80 % of the scenes, with at
#: least 80 % of its mean progress.
BARS = dict(mean=972.0, q1=967.0, share_vs_degroot=0.80, progress_ratio_vs_degroot=0.80)


def write_json(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as JSON atomically (a temporary file in the same folder, then rename)."""
    path = Path(path)
    tmp = path.with_suffix(path.suffix + f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(obj, indent=1, default=_json_default))
    os.replace(tmp, path)


def remove_temp_files(folder: str | Path) -> list[Path]:
    """Delete the temporary files :func:`write_json` / :func:`write_results` leave in ``folder``
    when their process is killed mid-write (``NAME.tmpPID``); returns the paths removed.  Call it
    only when no writer is running in the folder."""
    removed = []
    folder = Path(folder)
    if not folder.is_dir():
        return removed
    for p in folder.iterdir():
        suffix = p.suffix
        if suffix.startswith(".tmp") and suffix[4:].isdigit() and p.is_file():
            try:
                p.unlink()
                removed.append(p)
            except OSError:
                pass
    return removed


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")


def write_results(
    rows: Iterable[dict[str, Any]], path: str | Path, columns: Sequence[str] = RESULT_COLUMNS
) -> None:
    """Write rows to CSV atomically with ``columns`` first (extra keys appended, sorted)."""
    rows = list(rows)
    extra = sorted({k for r in rows for k in r} - set(columns))
    cols = list(columns) + extra
    path = Path(path)
    tmp = path.with_suffix(path.suffix + f".tmp{os.getpid()}")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in cols})
    os.replace(tmp, path)


def read_results(path: str | Path) -> list[dict[str, Any]]:
    """Read a ``results.csv`` back (numbers parsed, booleans as bool)."""
    out = []
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            out.append({k: _parse(v) for k, v in r.items()})
    return out


#: the tables the benchmarks write, in the order :func:`load_results` looks for them
RESULT_TABLES = ("results", "reduced_set", "timing", "frontier", "episodes")


def load_results(path: str | Path, table: str | None = None) -> Any:
    """A benchmark folder's table(s) as a ``pandas.DataFrame`` (``pip install "mmdopt[pandas]"``).

    Parameters
    ----------
    path : an ``--out`` folder of ``mmdopt bench ...`` (or one of its CSV files)
    table : one of :data:`RESULT_TABLES` (``"results"``, ``"reduced_set"``, ``"timing"``,
        ``"frontier"``, ``"episodes"``); default: whichever ``<table>.csv`` the folder holds

    Returns
    -------
    pandas.DataFrame with the CSV's columns (numbers parsed, ``True``/``False`` as bool).  When
    the folder holds several of the tables and ``table`` is not given, they are concatenated
    with a first column ``table`` naming each row's file.

    Raises
    ------
    FileNotFoundError
        if ``path`` does not exist or holds none of the tables (the names looked for are listed).
    ValueError
        for an unknown ``table``.
    ImportError
        if pandas is not installed.
    """
    from ._optional import require

    pd = require("pandas", "load_results")
    if table is not None and table not in RESULT_TABLES:
        raise ValueError(f"table must be one of {RESULT_TABLES}, got {table!r}")
    p = Path(path)
    if p.is_file():
        files = {p.stem: p}
    elif p.is_dir():
        names = RESULT_TABLES if table is None else (table,)
        files = {t: p / f"{t}.csv" for t in names if (p / f"{t}.csv").is_file()}
    else:
        raise FileNotFoundError(f"{p} does not exist")
    if not files:
        looked = ", ".join(f"{t}.csv" for t in (RESULT_TABLES if table is None else (table,)))
        raise FileNotFoundError(f"{p} holds no benchmark table (looked for {looked})")
    frames = {t: pd.read_csv(f) for t, f in files.items()}
    old = frames.get("frontier")
    if old is not None and "knob" in old.columns and "risk" not in old.columns:
        frames["frontier"] = old.rename(columns={"knob": "risk"})  # the column's older name
    if len(frames) == 1:
        return next(iter(frames.values()))
    return pd.concat(
        [df.assign(table=t)[["table", *df.columns]] for t, df in frames.items()],
        ignore_index=True,
    )


def _parse(v: str):
    if v in ("True", "False"):
        return v == "True"
    try:
        i = int(v)
        return i
    except ValueError:
        pass
    try:
        return float(v)
    except ValueError:
        return v


# ---------------------------------------------------------------------------------------------
# summary


def _stats(x: np.ndarray) -> dict[str, float]:
    x = np.asarray(x, dtype=np.float64)
    if x.size == 0:
        return {}
    q1, med, q3 = np.percentile(x, [25, 50, 75])
    return dict(
        mean=float(x.mean()),
        std=float(x.std()),
        min=float(x.min()),
        q1=float(q1),
        median=float(med),
        q3=float(q3),
        max=float(x.max()),
    )


def summarize(rows: Sequence[dict[str, Any]], reference: str = "mmd") -> dict[str, Any]:
    """Per-method statistics over scenes and the pairwise comparison with ``reference``.

    Returns ``{"methods": {m: {...}}, "vs": {baseline: {...}}}``: collision-free mean / std /
    min / quartiles, feasible share, progress and plan time per method; for every baseline the
    share of scenes where ``reference ≥ baseline`` (ties count as success), on the
    scenes both completed, and the ratio of mean progress.
    """
    by: dict[str, dict[int, dict[str, Any]]] = {}
    for r in rows:
        by.setdefault(str(r["method"]), {})[int(r["scene"])] = r
    out: dict[str, Any] = {"methods": {}, "vs": {}}
    for m, d in by.items():
        rs = list(d.values())
        cf_ = np.array([r["collision_free"] for r in rs], dtype=float)
        nv = np.array([r["n_validation"] for r in rs], dtype=float)
        out["methods"][m] = dict(
            scenes=len(rs),
            collision_free=_stats(cf_),
            collision_free_pct=float(np.mean(cf_ / nv) * 100),
            feasible_share=float(np.mean([bool(r["feasible"]) for r in rs])),
            fallback_share=float(np.mean([bool(r.get("fallback", False)) for r in rs])),
            progress_m=_stats([r["progress_m"] for r in rs]),
            mean_speed=float(np.mean([r["mean_speed"] for r in rs])),
            plan_time_s=_stats([r["plan_time_s"] for r in rs]),
        )
    if reference in by:
        ref = by[reference]
        for m, d in by.items():
            if m == reference:
                continue
            common = sorted(set(ref) & set(d))
            if not common:
                continue
            a = np.array([ref[s]["collision_free"] for s in common], dtype=float)
            b = np.array([d[s]["collision_free"] for s in common], dtype=float)
            pa = np.mean([ref[s]["progress_m"] for s in common])
            pb = np.mean([d[s]["progress_m"] for s in common])
            out["vs"][m] = dict(
                scenes=len(common),
                share_ge=float(np.mean(a >= b)),
                share_gt=float(np.mean(a > b)),
                mean_diff=float(np.mean(a - b)),
                progress_ratio=float(pa / pb) if pb > 0 else math.nan,
            )
    return out


def check_bars(summary: dict[str, Any], reference: str = "mmd", baseline: str = "degroot"):
    """:data:`BARS` against a summary: ``{bar: {"value", "target", "ok"}}``."""
    res = {}
    m = summary["methods"].get(reference)
    if m:
        res["mean"] = (m["collision_free"]["mean"], BARS["mean"])
        res["q1"] = (m["collision_free"]["q1"], BARS["q1"])
    v = summary["vs"].get(baseline)
    if v:
        res["share_vs_degroot"] = (v["share_ge"], BARS["share_vs_degroot"])
        res["progress_ratio_vs_degroot"] = (v["progress_ratio"], BARS["progress_ratio_vs_degroot"])
    return {k: dict(value=a, target=b, ok=bool(a >= b)) for k, (a, b) in res.items()}
