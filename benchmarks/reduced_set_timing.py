"""How long does reduced-set selection take at the paper's sizes (n = 100 samples, K = 100 steps)?

For each m and method: the first call (trace + XLA compile + run; m is static, so every m
compiles once) and the steady-state time of the public ``select_reduced_set`` (input validation
included; median and 90th percentile over fresh keys; also the process CPU time, a proxy less
sensitive to a shared, loaded machine, and its ratio to herding's at the same m measured in the
same run, the steadiest figure when other jobs share the CPU), on whatever device JAX picks.
Data: a two-intent lane-keep / lane-change mixture (p = 0.8 / 0.2), the same generator as
tests/mmdopt/test_reduced_set.py; the table also gives the share of the set drawn from the likely
intent and the MMD² of the weighted reduced set against all samples.

    python benchmarks/reduced_set_timing.py                    # m = 10 … 50, all methods
    python benchmarks/reduced_set_timing.py --methods mmd --repeats 50
    python benchmarks/reduced_set_timing.py --reference        # the reference's CEM settings too
    python benchmarks/reduced_set_timing.py --quality 40       # selection quality, 40 mixtures
    python benchmarks/reduced_set_timing.py --samplers 100 300 1000   # CEM Σ: Cholesky vs factor
    python benchmarks/reduced_set_timing.py --grams 300 1000 --m 20   # CEM MMD²: full vs low rank
    python benchmarks/reduced_set_timing.py --grams 1000 --m 20 --data paper100 --seeds 40
"""

from __future__ import annotations

import argparse
import platform
import time

import jax
import numpy as np

from mmdopt.reduced_set import (
    SELECTORS,
    ReducedSetConfig,
    select_reduced_set,
    select_reduced_set_unchecked,
)


def two_intent(seed: int, n: int = 100, k: int = 100, p_keep: float = 0.8, dt: float = 0.1):
    rng = np.random.default_rng(seed)
    t = np.arange(k) * dt
    keep = rng.random(n) < p_keep
    v = rng.normal(5.0, 1.0, n)
    s = np.clip(t / 4.0, 0.0, 1.0)
    y = np.where(keep[:, None], 0.0, 3.5 * (3 * s**2 - 2 * s**3)[None])
    y = y + rng.normal(0.0, 0.05, n)[:, None]
    return np.stack([v[:, None] * t, y], axis=-1), keep


def run(ms, methods, repeats, configs):
    X, keep = two_intent(0)
    ego = np.stack([10.0 * np.arange(100) * 0.1 - 10.0, np.zeros(100)], -1)
    rows = []
    for cname, cfg in configs.items():
        for method in methods if cname == "default" else ["mmd"]:
            for m in ms:
                t0 = time.perf_counter()
                rs = select_reduced_set(jax.random.key(0), X, m, method, cfg, ego)
                jax.block_until_ready(rs)
                first = time.perf_counter() - t0
                times, cpu, fracs, mmds = [], [], [], []
                for r in range(repeats):
                    key = jax.random.key(r + 1)
                    t0, c0 = time.perf_counter(), time.process_time()
                    rs = select_reduced_set(key, X, m, method, cfg, ego)
                    jax.block_until_ready(rs)
                    times.append(time.perf_counter() - t0)
                    cpu.append(time.process_time() - c0)
                    fracs.append(keep[np.asarray(rs.indices)].mean())
                    mmds.append(float(rs.mmd2))
                t = np.array(times) * 1e3
                c = float(np.median(cpu)) * 1e3
                row = (cname, method, m, first, np.median(t), np.percentile(t, 90), c)
                rows.append(row + (np.mean(fracs), np.median(mmds)))
                print(
                    f"{cname:9s} {method:8s} m={m:3d}  first {first:7.2f} s  "
                    f"steady {np.median(t):8.2f} ms (p90 {np.percentile(t, 90):8.2f}, "
                    f"CPU {c:8.2f})  likely {np.mean(fracs):.2f}  mmd2 {np.median(mmds):.2e}",
                    flush=True,
                )
    return rows


def quality(seeds: int, p_keep: float):
    """Share from the likely intent and MMD² over many mixtures (m = 10), per method/config."""
    from mmdopt.kernels import median_heuristic, mmd2_weighted

    variants = {
        "mmd (default)": ("mmd", ReducedSetConfig()),
        "mmd (reference settings, signed KKT)": ("mmd", ReducedSetConfig.reference()),
        "mmd (reference settings, simplex)": (
            "mmd",
            ReducedSetConfig.reference(weights="simplex"),
        ),
        "herding": ("herding", ReducedSetConfig()),
        "random": ("random", ReducedSetConfig()),
        "degroot": ("degroot", ReducedSetConfig()),
    }
    ego = np.stack([10.0 * np.arange(100) * 0.1 - 10.0, np.zeros(100)], -1)
    print(
        f"| method (m = 10, {seeds} mixtures, p = {p_keep}) | mean share from likely intent "
        "| seeds with share ≥ 0.8 | median MMD² (median-heuristic kernel) |"
    )
    print("|---|---|---|---|")
    for name, (method, cfg) in variants.items():
        share, mmd = [], []
        for seed in range(seeds):
            X, keep = two_intent(seed, p_keep=p_keep)
            likely = keep if p_keep >= 0.5 else ~keep
            rs = select_reduced_set_unchecked(jax.random.key(seed), X, 10, method, cfg, ego)
            idx = np.asarray(rs.indices)
            F = X.reshape(100, -1)
            u = np.full(100, 0.01)
            mmd.append(float(mmd2_weighted(F, u, F[idx], rs.weights, median_heuristic(F))))
            share.append(likely[idx].mean())
        share = np.array(share)
        print(
            f"| {name} | {share.mean():.3f} | {np.mean(share >= 0.8):.2f} | {np.median(mmd):.2e} |",
            flush=True,
        )


def paper100_samples(seed: int, n: int):
    """The planning samples of ``paper100`` scene ``seed`` of the tuning seed 777 with n samples
    per obstacle, and whether each is of the scene's likelier intent."""
    import dataclasses

    from mmdopt.bench.scenes import make_scene, preset

    sc = make_scene(seed, 777, dataclasses.replace(preset("paper100"), n_samples=n))
    X = np.asarray(sc.obstacles[0], np.float64)
    return X, np.asarray(sc.intents) == int(np.argmax(sc.intent_probs))


def compare_modes(
    ns, seeds: int, m: int, repeats: int, field: str = "sampler", values=None, data=two_intent
):
    """The MMD CEM's two ways to draw from N(μ, Σ) (``ReducedSetConfig.sampler``) at n samples
    (or, ``field="gram"``, its two ways to evaluate the population's MMD²: the full K or its
    low-rank factor): steady time per selection (median over ``repeats`` keys, after a first
    call that compiles) and, over ``seeds`` mixtures, the median MMD² of the refined set and the
    share of the set from the likely intent.  Ratios to the first mode's in the same run."""
    values = ("cholesky", "factor") if values is None else values
    print(f"# data: {data.__name__}")
    print(
        f"| n | {field} | first call (s) | steady median (s) | time ÷ {values[0]}'s "
        f"| median MMD² ({seeds} mixtures) | MMD² ÷ {values[0]}'s | share from likely intent |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for n in ns:
        X, _ = data(0, n=n)
        base = {}
        for value in values:
            cfg = ReducedSetConfig(**{field: value})
            t0 = time.perf_counter()
            jax.block_until_ready(select_reduced_set(jax.random.key(0), X, m, "mmd", cfg))
            first = time.perf_counter() - t0
            times = []
            for r in range(repeats):
                t0 = time.perf_counter()
                jax.block_until_ready(select_reduced_set(jax.random.key(r + 1), X, m, "mmd", cfg))
                times.append(time.perf_counter() - t0)
            mmd, share = [], []
            for seed in range(seeds):
                Xs, keep = data(seed, n=n)
                rs = select_reduced_set(jax.random.key(seed), Xs, m, "mmd", cfg)
                mmd.append(float(rs.mmd2))
                share.append(keep[np.asarray(rs.indices)].mean())
            t, q = float(np.median(times)), float(np.median(mmd))
            base.setdefault("t", t)
            base.setdefault("q", q)
            print(
                f"| {n} | {value} | {first:.2f} | {t:.3f} | {t / base['t']:.2f} | {q:.2e} "
                f"| {q / base['q']:.2f} | {np.mean(share):.2f} |",
                flush=True,
            )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, nargs="+", default=[10, 20, 30, 40, 50])
    ap.add_argument(
        "--methods",
        nargs="+",
        default=list(SELECTORS),
        help="selectors (mmdopt.reduced_set.SELECTORS; former names accepted)",
    )
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument(
        "--reference",
        action="store_true",
        help="also time ReducedSetConfig.reference() (α-scale 1, β = 1, signed KKT)",
    )
    ap.add_argument(
        "--quality",
        type=int,
        default=0,
        metavar="SEEDS",
        help="instead of timing, compare selection quality over SEEDS mixtures",
    )
    ap.add_argument("--p-keep", type=float, default=0.8)
    ap.add_argument(
        "--samplers",
        type=int,
        nargs="+",
        metavar="N",
        help="instead of timing, compare the CEM samplers (Cholesky / factor) at these n",
    )
    ap.add_argument(
        "--grams",
        type=int,
        nargs="+",
        metavar="N",
        help="instead of timing, compare the CEM's MMD² (full K / low-rank factor) at these n",
    )
    ap.add_argument("--seeds", type=int, default=10, help="mixtures per n for --samplers/--grams")
    ap.add_argument(
        "--data",
        choices=("two_intent", "paper100"),
        default="two_intent",
        help="samples for --samplers/--grams: the two-intent mixture or paper100 tuning scenes",
    )
    args = ap.parse_args()
    if args.samplers:
        compare_modes(args.samplers, args.seeds, args.m[0], args.repeats)
        return
    if args.grams:
        data = two_intent if args.data == "two_intent" else paper100_samples
        compare_modes(
            args.grams, args.seeds, args.m[0], args.repeats, "gram", ("full", "lowrank"), data
        )
        return
    if args.quality:
        quality(args.quality, args.p_keep)
        return
    configs = {"default": ReducedSetConfig()}
    if args.reference:
        configs["reference"] = ReducedSetConfig.reference()
    dev = jax.devices()[0]
    print(
        f"# device: {dev.platform} {getattr(dev, 'device_kind', '')}; jax {jax.__version__}; "
        f"{platform.processor() or platform.machine()}; n = 100, K = 100, float64"
    )
    rows = run(args.m, args.methods, args.repeats, configs)
    herding = {m: cpu for c, meth, m, _, _, _, cpu, _, _ in rows if meth == "herding"}
    print()
    print(
        "| config | method | m | first call (s) | steady median (ms) | p90 (ms) "
        "| CPU time median (ms) | CPU ÷ herding's | share from likely intent | MMD² |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for c, meth, m, first, med, p90, cpu, frac, mmd in rows:
        ratio = f"{cpu / herding[m]:.1f}" if m in herding else "–"
        print(
            f"| {c} | {meth} | {m} | {first:.2f} | {med:.2f} | {p90:.2f} | {cpu:.2f} | {ratio} "
            f"| {frac:.2f} | {mmd:.1e} |"
        )


if __name__ == "__main__":
    main()
