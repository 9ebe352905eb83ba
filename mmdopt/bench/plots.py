"""Figures of the experiments (matplotlib, Agg-safe): paper Figs. 3, 4, 5 and Table II as a plot.

Every function takes plain data (result rows, arrays) and writes one PNG; none needs a display.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

import mmdopt.methods

from ._optional import require

__all__ = [
    "method_label",
    "method_colour",
    "collision_box_violin",
    "scene_figure",
    "demo_figure",
    "reduced_set_figure",
    "timing_figure",
    "reduced_set_indices",
]

#: names of selections that are not plan methods (the reduced-set benchmark's herding)
_OTHER_LABELS = {"herding": "kernel herding"}
_OTHER_COLOURS = {"herding": "tab:cyan"}


def method_label(name: str) -> str:
    """How tables and figures name ``name``: its record's label (:mod:`mmdopt.methods`)."""
    if name in mmdopt.methods.names():
        return mmdopt.methods.get(name).label
    return _OTHER_LABELS.get(name, name)


def method_colour(name: str) -> str | None:
    """The colour figures draw ``name`` in: its record's colour (``None``: matplotlib's)."""
    if name in mmdopt.methods.names():
        return mmdopt.methods.get(name).colour
    return _OTHER_COLOURS.get(name)


def pyplot():
    """``matplotlib.pyplot`` on a non-interactive backend (Agg unless the caller chose a file
    backend), so figures are written without a display."""
    matplotlib = require("matplotlib", "plotting")

    if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg", "cairo"):
        try:
            matplotlib.use("Agg")
        except Exception:  # pragma: no cover - backend already fixed by the caller
            pass
    import matplotlib.pyplot as plt

    return plt


def _box_legend(ax, plt) -> None:
    """Legend for matplotlib's box plot marks (``showmeans=True``)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    ax.legend(
        handles=[
            Patch(facecolor="none", edgecolor="k", label="box: quartiles Q1–Q3"),
            Line2D([], [], color="tab:orange", lw=1.5, label="median"),
            Line2D([], [], marker="^", color="tab:green", ls="none", ms=7, label="mean"),
            Line2D([], [], color="k", lw=1, label="whiskers: last scene within 1.5 × IQR"),
            Line2D([], [], marker="o", mfc="none", mec="k", ls="none", ms=5, label="outlier scene"),
        ],
        fontsize=7,
        loc="best",
        framealpha=0.85,
    )


def collision_box_violin(
    rows: Sequence[Mapping[str, Any]],
    path: str | Path,
    methods: Sequence[str] | None = None,
    title: str | None = None,
) -> Path:
    """Paper Fig. 5: box and violin plots of collision-free validation samples per method,
    with a third panel for progress (m) so a method cannot win by standing still.  One point per
    scene; every mark is explained in the panels' legends."""
    plt = pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    methods = list(methods or dict.fromkeys(r["method"] for r in rows))
    data = [
        np.array([r["collision_free"] for r in rows if r["method"] == m], float) for m in methods
    ]
    prog = [np.array([r["progress_m"] for r in rows if r["method"] == m], float) for m in methods]
    keep = [i for i, d in enumerate(data) if d.size]
    methods = [methods[i] for i in keep]
    data, prog = [data[i] for i in keep], [prog[i] for i in keep]
    labels = [method_label(m) for m in methods]
    nvs = sorted({int(r["n_validation"]) for r in rows if "n_validation" in r})
    of = f"of {nvs[0]}" if len(nvs) == 1 else "count"
    fig, axs = plt.subplots(1, 3, figsize=(15, 4.8))
    axs[0].boxplot(data, tick_labels=labels, showmeans=True)
    axs[0].set_title("collision-free validation samples per scene (box)", fontsize=10)
    axs[0].set_ylabel(f"collision-free validation samples ({of})")
    _box_legend(axs[0], plt)
    parts = axs[1].violinplot(data, showmedians=True)
    for body, m in zip(parts["bodies"], methods, strict=True):
        body.set_facecolor(method_colour(m) or "tab:blue")
    axs[1].set_xticks(range(1, len(labels) + 1), labels)
    axs[1].set_title("collision-free validation samples per scene (violin)", fontsize=10)
    axs[1].set_ylabel(f"collision-free validation samples ({of})")
    axs[1].legend(
        handles=[
            Patch(facecolor=(method_colour(m) or "tab:blue"), alpha=0.5, label=f"{lab}: density")
            for m, lab in zip(methods, labels, strict=True)
        ]
        + [
            Line2D([], [], color="tab:blue", lw=1.5, label="median (middle bar)"),
            Line2D([], [], color="tab:blue", lw=1, label="min / max (end bars)"),
        ],
        fontsize=7,
        loc="best",
        framealpha=0.85,
    )
    axs[2].boxplot(prog, tick_labels=labels, showmeans=True)
    axs[2].set_title("progress along the road over the 15 s horizon", fontsize=10)
    axs[2].set_ylabel("progress (m)")
    _box_legend(axs[2], plt)
    for ax in axs:
        ax.set_xlabel("method")
        ax.tick_params(axis="x", labelrotation=20)
        ax.grid(alpha=0.3)
    n = data[0].size if data else 0
    fig.suptitle(title or f"{n} scenes")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def reduced_set_indices(plan) -> np.ndarray | None:
    """The reduced set of the first obstacle of a plan, as indices (None if the plan has none)."""
    rs = getattr(plan, "reduced_set", None)
    if rs is None:
        return None
    if isinstance(rs, Mapping):
        rs = rs.get("indices", rs.get(0))
    if isinstance(rs, (list, tuple)) and rs and not np.isscalar(rs[0]):
        rs = rs[0]
    idx = getattr(rs, "indices", rs)
    if idx is None:
        return None
    idx = np.asarray(idx)
    if idx.ndim == 2:
        idx = idx[0]
    return idx.astype(int) if idx.size else None


def _default_validation_index(scene) -> int:
    """A validation sample of the less probable intent, if there is one."""
    rare = int(np.argmin(scene.intent_probs))
    cand = np.flatnonzero(scene.validation_intents == rare)
    return int(cand[0]) if cand.size else 0


def _scene_xlim(scene, plans: Mapping[str, Any], validation_index: int) -> tuple[float, float]:
    """x range (m) of what a scene panel draws: the samples, the plans, the validation sample."""
    obs = np.asarray(scene.obstacles[0])[..., 0]
    xs = [obs.min(), obs.max()]
    xs += [float(np.min(plan.x)) for plan in plans.values()]
    xs += [float(np.max(plan.x)) for plan in plans.values()]
    v = np.asarray(scene.validation[0])[validation_index, :, 0]
    xs += [v.min(), v.max()]
    return float(min(xs)) - 5.0, float(max(xs)) + 5.0


def _footprint(plan) -> tuple[float, float] | None:
    """The collision ellipse's semi-axes ``(a, b)`` the plan was made with (``None``: unknown)."""
    cfg = getattr(plan, "config", None)
    fp = getattr(getattr(cfg, "safety", None), "footprint", None)
    return None if fp is None else (float(fp.a), float(fp.b))


def _scene_panel(ax, scene, m: str, plan, validation_index: int, title: str | None = None):
    """One method's panel of :func:`scene_figure`: samples, reduced set, hits, plan, legend."""
    from matplotlib.lines import Line2D

    from mmdopt.collision import collision_free_count

    obs = np.asarray(scene.obstacles[0])
    val = np.asarray(scene.validation[0])
    xy = np.stack([np.asarray(plan.x), np.asarray(plan.y)], -1)
    t = np.asarray(getattr(plan, "t", np.arange(xy.shape[0])))
    every = int(dt_every(t, 1.5))
    for y in (-3.5, 0.0, 3.5):
        ax.axhline(y, color="k", lw=0.5, ls=":")
    for y in (-5.25, -1.75, 1.75, 5.25):
        ax.axhline(y, color="k", lw=0.8)
    for intent in np.unique(scene.intents):
        sel = obs[scene.intents == intent]
        ax.plot(sel[:, :, 0].T, sel[:, :, 1].T, color="0.7", lw=0.6, alpha=0.6)
    col = method_colour(m) or "m"
    handles = [
        Line2D([], [], color="0.7", lw=1, label=f"planning samples ({obs.shape[0]})"),
    ]
    idx = reduced_set_indices(plan)
    if idx is not None:
        rs = obs[idx]
        ax.plot(rs[:, :, 0].T, rs[:, :, 1].T, color=col, lw=1.6, zorder=2)
        handles.append(
            Line2D([], [], color=col, lw=1.6, label=f"reduced set used by the cost ({idx.size})")
        )
    counts = collision_free_count(xy, val[None])
    hit = np.asarray(counts.colliding)[0]
    if hit.any():
        hv = val[hit][:50]
        # on top of the reduced set: the hits are what the panel is about
        ax.plot(hv[:, :, 0].T, hv[:, :, 1].T, color="red", lw=0.9, alpha=0.8, zorder=4)
        handles.append(
            Line2D(
                [], [], color="red", lw=0.9,
                label=f"validation samples the plan hits ({int(hit.sum())}"
                + (", 50 drawn)" if hit.sum() > 50 else ")"),
            )
        )  # fmt: skip
    v = val[validation_index]
    ax.plot(v[:, 0], v[:, 1], "k--", lw=1.0)
    ax.plot(v[::every, 0], v[::every, 1], "ks", ms=3)
    handles.append(
        Line2D(
            [], [], color="k", ls="--", marker="s", ms=3, lw=1.0,
            label=f"one validation sample (■ every {t[every] - t[0]:.1f} s)",
        )
    )  # fmt: skip
    pc = "k"  # the plan in black in every panel (the reduced set has the method colour)
    ax.plot(xy[:, 0], xy[:, 1], color=pc, lw=2, zorder=5)
    ax.plot(xy[::every, 0], xy[::every, 1], "o", color=pc, ms=4, zorder=5)
    fp = _footprint(plan)
    if fp is not None:  # what "unsafe" means: a sample's circle inside this ellipse
        from matplotlib.patches import Ellipse

        for x0, y0 in xy[::every][1::2]:
            ax.add_patch(Ellipse((x0, y0), 2 * fp[0], 2 * fp[1], fill=False, ec=pc, lw=0.6,
                                 ls="-", alpha=0.45, zorder=3))  # fmt: skip
        handles.append(
            Line2D([], [], color=pc, lw=0.6, alpha=0.45,
                   label=f"collision ellipse (semi-axes {fp[0]:g} m, {fp[1]:g} m)")
        )  # fmt: skip
    handles += [
        Line2D(
            [], [], color=pc, lw=2, marker="o", ms=4,
            label=f"ego plan (● every {t[every] - t[0]:.1f} s)",
        ),
        Line2D([], [], color="k", lw=0.8, label="lane boundary"),
        Line2D([], [], color="k", lw=0.5, ls=":", label="lane centre"),
    ]  # fmt: skip
    ax.legend(
        handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.005, 1.0),
        borderaxespad=0.0,
    )  # fmt: skip
    cf_ = int(counts.joint)
    prog = float(np.asarray(plan.s)[-1] - np.asarray(plan.s)[0])
    ax.set_title(
        f"{title or method_label(m)}: {cf_}/{val.shape[0]} validation samples collision-free, "
        f"progress {prog:.0f} m",
        fontsize=10,
    )
    ax.set_ylim(-6, 6)
    ax.set_ylabel("y (m)")
    ax.set_xlabel("x (m)")


def _scene_title(scene) -> str:
    off, p = float(scene.params.intent_offsets[0]), float(scene.intent_probs[0])
    where = "into the ego's lane" if off == 0.0 else f"to the lane at y = {off:g} m"
    return (
        f"scene {scene.index}: a car at x = {scene.x0:.0f} m, y = {scene.y0:.1f} m moves "
        f"{where} with probability {p:.2f}"
    )


def scene_figure(
    scene,
    plans: Mapping[str, Any],
    path: str | Path,
    validation_index: int | None = None,
    title: str | None = None,
) -> Path:
    """Paper Fig. 3 style: one panel per method with the planning samples (grey: by intent),
    the method's reduced set (coloured), its plan (ego positions every 1.5 s) and the validation
    samples it collides with (red), plus one validation sample with its positions at the plan's
    time steps (black dashed).  The x axis spans what is drawn."""
    plt = pyplot()
    n = len(plans)
    fig, axs = plt.subplots(n, 1, figsize=(15, 3.1 * n), squeeze=False)
    if validation_index is None:
        validation_index = _default_validation_index(scene)
    xlim = _scene_xlim(scene, plans, validation_index)
    for ax, (m, plan) in zip(axs[:, 0], plans.items(), strict=True):
        _scene_panel(ax, scene, m, plan, validation_index)
        ax.set_xlim(*xlim)
    fig.suptitle(title or _scene_title(scene), fontsize=11)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def demo_figure(
    scene,
    plans: Mapping[str, Any],
    points: Sequence[Mapping[str, Any]],
    path: str | Path,
    risk: float,
    validation_index: int | None = None,
) -> Path:
    """The demo's figure: :func:`scene_figure`'s panels of each method's plan at risk level
    ``risk`` (left), and a safety–progress panel (right): collision-free validation samples
    against progress, one line per method through its risk levels ε, each point labelled with
    its ε (``points``: rows with ``method``, ``risk``, ``collision_free``, ``n_validation``,
    ``progress_m``, as the demo's table)."""
    plt = pyplot()
    n = len(plans)
    fig = plt.figure(figsize=(18, max(3.6 * n, 5.0)))
    # the middle column holds the scene panels' legends
    gs = fig.add_gridspec(n, 3, width_ratios=[3.0, 1.4, 1.25], wspace=0.05, hspace=0.45)
    if validation_index is None:
        validation_index = _default_validation_index(scene)
    xlim = _scene_xlim(scene, plans, validation_index)
    for i, (m, plan) in enumerate(plans.items()):
        ax = fig.add_subplot(gs[i, 0])
        _scene_panel(
            ax, scene, m, plan, validation_index, title=f"{method_label(m)} at ε = {risk:g}"
        )
        ax.set_xlim(*xlim)
    ax = fig.add_subplot(gs[:, 2])
    nvs = sorted({int(p["n_validation"]) for p in points})
    for k, m in enumerate(dict.fromkeys(p["method"] for p in points)):
        pts = sorted((p for p in points if p["method"] == m), key=lambda p: p["progress_m"])
        x = [float(p["progress_m"]) for p in pts]
        y = [int(p["collision_free"]) for p in pts]
        col = method_colour(m) or "tab:blue"
        ax.plot(x, y, "o-", color=col, label=f"{method_label(m)} ({m})")
        same: dict[tuple[float, int], list[str]] = {}  # one label per drawn point
        for p, xi, yi in zip(pts, x, y, strict=True):
            same.setdefault((round(xi, 1), yi), []).append(f"{float(p['risk']):g}")
        for (xi, yi), eps in same.items():
            ax.annotate(
                "ε=" + ", ".join(sorted(eps, key=float)), (xi, yi), textcoords="offset points",
                xytext=(5, 4 if k % 2 == 0 else -10), ha="left", fontsize=7, color=col,
            )  # fmt: skip
    xs = [float(p["progress_m"]) for p in points]
    ys = [int(p["collision_free"]) for p in points]
    if xs:
        dx = max(1.0, 0.12 * (max(xs) - min(xs)))
        dy = max(1.0, 0.12 * (max(ys) - min(ys)))
        ax.set_xlim(min(xs) - 2 * dx, max(xs) + 2 * dx)
        ax.set_ylim(min(ys) - dy, min(max(ys) + 2 * dy, (nvs[-1] if nvs else max(ys)) + dy))
    ax.set_xlabel("progress over the horizon (m)")
    ax.set_ylabel(f"collision-free validation samples (of {nvs[0] if len(nvs) == 1 else 'N'})")
    ax.set_title("safety vs progress: one point per risk level ε", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left", title="method (demo table)", title_fontsize=7)
    fig.suptitle(_scene_title(scene), fontsize=11)
    path = Path(path)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def dt_every(t: np.ndarray, seconds: float) -> int:
    """The number of grid steps closest to ``seconds`` on the time grid ``t`` (at least 1)."""
    t = np.asarray(t, float)
    if t.size < 2:
        return 1
    return max(1, int(round(seconds / float(t[1] - t[0]))))


RS_LABELS = {
    "mmd": "MMD selection (ours)",
    "herding": "kernel herding",
    "degroot": "de Groot set",
    "random": "random set",
}


def _rs_label(m: str) -> str:
    return RS_LABELS.get(m, m)


def reduced_set_figure(
    per_scene: Mapping[str, Sequence[float]],
    random_sets: Sequence[Sequence[float]],
    path: str | Path,
    n_validation: int = 1000,
) -> Path:
    """Paper Fig. 4: (a) mean ± std of collision-free validation samples per reduced-set method
    and for the random reduced sets (the near-exhaustive search); (b) per scene, every random
    set's count (dots) against each method's."""
    plt = pyplot()
    fig, axs = plt.subplots(1, 2, figsize=(13, 4.2), gridspec_kw=dict(width_ratios=[1, 2]))
    names = list(per_scene)
    means = [np.mean(per_scene[m]) / n_validation * 100 for m in names]
    stds = [np.std(per_scene[m]) / n_validation * 100 for m in names]
    rnd = np.array([np.mean(r) for r in random_sets]) / n_validation * 100
    rnd_best = np.array([np.max(r) for r in random_sets]) / n_validation * 100
    names_all = names + ["random sets (mean)", "random sets (best, oracle)"]
    means += [rnd.mean(), rnd_best.mean()]
    stds += [rnd.std(), rnd_best.std()]
    cols = [(method_colour(m) or "tab:blue") for m in names] + ["0.6", "0.3"]
    bars = axs[0].bar(
        range(len(names_all)),
        means,
        yerr=stds,
        color=cols,
        capsize=3,
    )
    axs[0].set_xticks(range(len(names_all)), [_rs_label(m) for m in names_all], rotation=25)
    axs[0].set_xlabel("reduced-set selection")
    axs[0].set_ylabel("collision-free validation samples (%)")
    axs[0].set_title(
        f"mean over {len(random_sets)} scenes of Algorithm 1 (MMD surrogate) on each reduced set",
        fontsize=9,
    )
    lo = min(m - s for m, s in zip(means, stds, strict=True))
    axs[0].set_ylim(max(0.0, lo - 5), 100.5)
    axs[0].grid(alpha=0.3, axis="y")
    from matplotlib.lines import Line2D

    for i, r in enumerate(random_sets):
        axs[1].plot(
            np.full(len(r), i),
            np.asarray(r) / n_validation * 100,
            ".",
            color="0.6",
            ms=3,
            label="one random reduced set (Algorithm 1 on it)" if i == 0 else None,
        )
    for m in names:
        axs[1].plot(
            range(len(per_scene[m])),
            np.asarray(per_scene[m]) / n_validation * 100,
            "_",
            ms=10,
            mew=2,
            color=(method_colour(m) or "tab:blue"),
            label=_rs_label(m),
        )
    axs[1].set_xticks(range(len(random_sets)))
    axs[1].set_xlabel("scene (index)")
    axs[1].set_ylabel("collision-free validation samples (%)")
    axs[1].set_title("per scene: each selection method against the random reduced sets", fontsize=9)
    axs[1].legend(fontsize=7)
    axs[1].grid(alpha=0.3)
    fig.tight_layout()
    # below panel (a), after the layout (bbox_inches='tight' keeps it in the PNG)
    axs[0].legend(
        handles=[*bars.patches, Line2D([], [], color="k", marker="_", ms=8, label="± 1 std")],
        labels=[_rs_label(m) for m in names_all] + ["error bar: ± 1 std over scenes"],
        fontsize=7,
        loc="upper center",
        bbox_to_anchor=(0.5, -0.5),
        ncol=2,
    )
    path = Path(path)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def timing_figure(rows: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    """Paper Table II as a plot: reduced-set selection and Algorithm 1 time vs reduced-set size
    (at the default sample count) and vs the number of samples."""
    plt = pyplot()
    fig, axs = plt.subplots(1, 2, figsize=(11, 3.8))
    n_def = max(
        {r["n_samples"] for r in rows}, key=lambda n: sum(r["n_samples"] == n for r in rows)
    )
    a = sorted((r for r in rows if r["n_samples"] == n_def), key=lambda r: r["reduced_set_size"])
    m_def = 10 if any(r["reduced_set_size"] == 10 for r in rows) else a[0]["reduced_set_size"]
    b = sorted((r for r in rows if r["reduced_set_size"] == m_def), key=lambda r: r["n_samples"])
    for ax, rs, key, xl in (
        (axs[0], a, "reduced_set_size", f"reduced-set size m (samples; n = {n_def})"),
        (axs[1], b, "n_samples", f"planning samples n (samples; m = {m_def})"),
    ):
        x = [r[key] for r in rs]
        ax.plot(x, [r["reduced_set_s"] * 1e3 for r in rs], "o-", label="reduced-set selection")
        ax.plot(x, [r["algorithm1_s"] * 1e3 for r in rs], "s-", label="Algorithm 1")
        ax.set_xlabel(xl)
        ax.set_ylabel("median wall time per call (ms)")
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
