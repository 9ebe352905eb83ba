"""The risk level: a target collision probability ε, and what follows from it.

``risk`` = ε is **the probability, under the predictor's distribution of futures, that the
plan's footprint meets an obstacle** (the collision ellipse of :class:`mmdopt.Footprint`
entered at any step by a future drawn from the same distribution as the planning samples);
1000 · (1 − ε) is the target collision-free count of the benchmarks' metric, which measures
exactly that on independent validation futures.  Every planning method of
:mod:`mmdopt.baselines` takes the same level: :func:`config_for_risk` derives the method's
margins, weights and chance level from ε, and :func:`mmdopt.plan` does it for
``plan(..., risk=ε)``.  The default :class:`~mmdopt.MMDOptConfig` *is* this mapping at
ε = ``safety.risk`` = 0.005 for every method (``margin_mode="samples"``, ``w_cover`` = 100,
automatic ``reselect`` and SAA chance level), so ``plan(..., method=m)`` plans as
``plan(..., method=m, risk=0.005)``; ``MMDOptConfig().replace(margin_mode="linear")`` keeps the
time-linear constants of the paper reproduction.

==================  =====================================================================
method              what ε sets
==================  =====================================================================
``"mmd"``           sample-driven margins (``margin_mode="samples"``): every reduced-set
                    point's ellipse is inflated, per time step, to contain the planning
                    samples of its cluster (those nearer to it than to any other point)
                    with probability 1 − ε under a Gaussian fit (z = Φ⁻¹(1 − ε)); the
                    MMD cost adds ``w_cover`` = 100 × Σ f̄ on the inflated ellipses
                    (entering any costs, whatever ᾱ); and a second, warm-started pass
                    with the m/2 samples in deepest conflict with the first plan added
                    to the reduced set (``reselect``), after skipping the ⌊ε·n⌋ deepest
                    (the conflicts a chance constraint at level ε may leave); then a pass
                    against the ``nearest_futures`` = 200 futures nearest to the plan with
                    SAA's chance term at the number of futures the 95 % bound lets the plan
                    meet (``hits_for_risk``) and loose margins (level 10ε), repeated with one
                    hit fewer while its plan breaks the bound; from a predictor it draws
                    enough futures for 40 allowed hits (``risk_hits``, about 52/ε)
``"random"``        the same margins and coverage term, no second pass
``"degroot"``       the same margins (its scenario cost is unchanged)
``"scenario_all"``  the same margins, each sample's cluster being its ``n // m`` nearest
                    samples (it plans against every sample already: the margin covers
                    the tail beyond the n samples)
``"saa"``           chance level ``saa_eps = ε`` (π̂ ≤ ε on the planning samples) plus the
                    same k-NN margins at 1 − ε
==================  =====================================================================

The margins (:func:`coverage_margins`): for point j of obstacle o at step k let ``e = s_i − s_j``
and ``u = d_i − d_j`` over the members i of j's cluster (j included).  With their mean μ and
variance v (shrunk towards the obstacle's pooled within-cluster variance with
``coverage_prior`` pseudo-samples, so that clusters of one or two samples get the typical spread
rather than none), the longitudinal margin **behind** the point (where a following ego meets the
slower futures) is ``max(0, z·σ_e − μ_e)``, **ahead** ``max(0, z·σ_e + μ_e)``, and the lateral
margin ``|μ_u| + z·σ_u``.  The old constants (2.5 m + 1.9 m/s·t, 0.4 m) were a fitted stand-in
for the same quantity: ≈ 1 σ of the speed spread integrated over time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
import scipy.sparse as sp

from . import methods as registry
from .config import MMDOptConfig

__all__ = [
    "RISK_CONFIDENCE",
    "config_for_risk",
    "coverage_margins",
    "coverage_data",
    "CoverageData",
    "risk_z",
    "check_risk",
    "clopper_pearson_upper",
    "risk_bound",
    "risk_floor",
    "samples_for_risk",
    "hits_for_risk",
]


def check_risk(risk: float, name: str = "risk") -> float:
    """``risk`` as a float in (0, 0.5), else ``ValueError`` naming ``name``."""
    if isinstance(risk, bool | str | bytes | complex):
        raise ValueError(f"{name} must be a number in (0, 0.5), got {risk!r}")
    try:
        r = float(risk)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in (0, 0.5), got {risk!r}") from None
    if not (math.isfinite(r) and 0.0 < r < 0.5):
        raise ValueError(f"{name} must be in (0, 0.5) (a collision probability), got {risk!r}")
    return r


def risk_z(eps: float) -> float:
    """z = Φ⁻¹(1 − ε): the standard-normal quantile of the coverage level."""
    return NormalDist().inv_cdf(1.0 - check_risk(eps, "eps"))


def config_for_risk(
    method: str | registry.PlanMethod, risk: float | None = None, config: MMDOptConfig | None = None
) -> MMDOptConfig:
    """``config`` (default ``MMDOptConfig()``) with ``method``'s margins, weights and chance level
    derived from the target collision probability ``risk`` (default: the method's
    :attr:`~mmdopt.methods.PlanMethod.default_risk`), by the record's rule
    (:meth:`~mmdopt.methods.PlanMethod.settings_for_risk`).

    See the module docstring for each method's mapping.  Raises ``ValueError`` for an unknown
    method or a risk outside (0, 0.5).
    """
    rec = registry.get(method)
    eps = rec.default_risk if risk is None else check_risk(risk)
    cfg = MMDOptConfig() if config is None else config
    if not isinstance(cfg, MMDOptConfig):
        raise ValueError(f"config must be an MMDOptConfig, got {type(cfg).__name__}")
    return cfg.replace(**rec.settings_for_risk(eps))


def _margins_from_moments(c, mu_e, mu_u, v_e, v_u, z, prior, h_e=0.0):
    """Margins (3, J, K) from each point's cluster size c (J, 1) and the mean μ and variance v
    (J, K) of its members' deviations (longitudinal e, lateral u)."""
    # pooled within-cluster variance per step (clusters weighted by size)
    pool_e = (c * v_e).sum(0) / c.sum()
    pool_u = (c * v_u).sum(0) / c.sum()
    sd_e = np.sqrt((c * v_e + prior * pool_e) / (c + prior) + h_e**2)
    sd_u = np.sqrt((c * v_u + prior * pool_u) / (c + prior))
    behind = np.maximum(z * sd_e - mu_e, 0.0)
    ahead = np.maximum(z * sd_e + mu_e, 0.0)
    lat = np.abs(mu_u) + z * sd_u
    return np.stack([behind, ahead, lat])


def _cluster_margins(flat, flat2, idx, M, z, prior, h_e=0.0):
    """Margins (3, J, K) of the clusters given by the (J, n) 0/1 membership matrix ``M``
    (``scipy.sparse``: a sample belongs to one cluster, or to ``knn`` of them) over the centred
    positions ``flat`` (n, 2K: s and d interleaved) of the samples and their squares ``flat2``;
    ``idx`` (J,) the points.
    The members' count, sum and sum of squares are two sparse products with ``M``: work in the
    members, not in J·n."""
    c = np.maximum(np.asarray(M.sum(1)).reshape(-1), 1.0)[:, None]
    mean = (M @ flat) / c
    mu = mean - flat[idx]  # mean deviation from the anchor
    v = np.maximum((M @ flat2) / c - mean * mean, 0.0)  # variance is shift-invariant
    return _margins_from_moments(c, mu[:, 0::2], mu[:, 1::2], v[:, 0::2], v[:, 1::2], z, prior, h_e)


@dataclass(frozen=True, eq=False)
class CoverageData:
    """What :func:`coverage_margins` computes from the samples before it looks at the points,
    per obstacle, for one ``lateral_scale``: the centred positions ``flat`` (R, 2K) of the
    samples ``rows`` (``None``: all n, R = n) about their mean ``centre`` (2K,), the squared
    norms ``FF`` (R,) of their copy with the lateral offsets scaled, ``flat²`` and the spread of
    the arc length per step (K,).  A planner that asks for the margins of several point sets
    among the same samples builds it once (:func:`coverage_data`); the margins are the same."""

    shape: tuple[int, int, int, int]
    lateral_scale: float
    flat: tuple[np.ndarray, ...]
    FF: tuple[np.ndarray, ...]
    flat2: tuple[np.ndarray, ...]
    std_s: tuple[np.ndarray, ...]
    centre: tuple[np.ndarray, ...] = ()
    rows: np.ndarray | None = None

    def obstacle(self, o: int) -> CoverageData:
        """The data of obstacle ``o`` alone (of the samples ``obstacles_frenet[o : o + 1]``)."""
        O, n, K, _ = self.shape
        if not 0 <= o < O:
            raise ValueError(f"o must be an obstacle in [0, {O}), got {o}")
        one = (self.flat, self.FF, self.flat2, self.std_s, self.centre)
        return CoverageData((1, n, K, 2), self.lateral_scale,
                            *(f[o : o + 1] for f in one), self.rows)  # fmt: skip


def coverage_data(
    obstacles_frenet: np.ndarray, lateral_scale: float = 1.0, rows: np.ndarray | None = None
) -> CoverageData:
    """:class:`CoverageData` of the (O, n, K, 2) planning samples for ``lateral_scale``, formed
    from the samples ``rows`` (R,) of each obstacle only (``None``: all n).  With rows, the
    margins are estimated from those samples (a random or evenly spaced subset of i.i.d.
    futures: the same clusters' spread, from R/n of the work) and every point joins its own
    cluster (:func:`coverage_margins`)."""
    X = np.asarray(obstacles_frenet)
    if X.ndim != 4 or X.shape[-1] != 2 or X.shape[1] == 0:
        raise ValueError(f"obstacles_frenet must have shape (O, n, K, 2), n >= 1, got {X.shape}")
    O, n, K, _ = X.shape
    if rows is not None:
        rows = np.asarray(rows)
        if (
            rows.ndim != 1
            or rows.size == 0
            or not np.issubdtype(rows.dtype, np.integer)
            or (rows.min() < 0 or rows.max() >= n)
        ):
            raise ValueError(f"rows must be a 1-D array of sample positions in [0, {n})")
    used = X if rows is None else _gather_rows(X, rows)
    if not np.all(np.isfinite(used)):
        raise ValueError("obstacles_frenet contains NaN or inf")
    scale2 = np.tile(np.array([1.0, float(lateral_scale) ** 2]), K)
    flat, FF, flat2, std_s, centre = [], [], [], [], []
    for o in range(O):
        # centred (R, 2K) positions: the expanded distances and sums of squares keep their
        # precision far from the origin
        f = np.asarray(used[o], np.float64).reshape(used.shape[1], -1)
        mean = f.mean(axis=0)
        f = f - mean  # (a new array: the caller's samples are left as they are)
        f2 = f * f
        flat.append(f)
        FF.append(f2 @ scale2)  # squared norms with the lateral offsets scaled
        flat2.append(f2)
        std_s.append(np.sqrt(f2[:, 0::2].mean(axis=0)))  # the arc length's spread per step
        centre.append(mean)
    return CoverageData(
        X.shape, float(lateral_scale), *map(tuple, (flat, FF, flat2, std_s, centre)), rows
    )


def _gather_rows(X: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``X[:, rows]`` (O, R, K, 2); from samples held as the count's planes (``X`` a transposed
    view of (O, 2, K, n), :mod:`mmdopt.counting`) gathered along the planes' rows, as a view
    of (O, 2, K, R) (a gather of (K, 2) blocks from that view reads one float per cache line)."""
    base = X.transpose(0, 3, 2, 1)
    if X.flags.c_contiguous or not base.flags.c_contiguous:
        return X[:, rows]
    return np.take(base, rows, axis=3).transpose(0, 3, 2, 1)


def coverage_margins(
    obstacles_frenet: np.ndarray,
    indices: np.ndarray,
    eps: float,
    *,
    lateral_scale: float = 1.0,
    prior: float = 2.0,
    knn: int = 0,
    bandwidth: float = 0.0,
    data: CoverageData | None = None,
    pool: np.ndarray | None = None,
) -> np.ndarray:
    """Sample-driven planning margins (m), shape (3, O, J, K): behind, ahead, lateral.

    ``obstacles_frenet`` (O, n, K, 2) all n planning samples (Frenet ``s, d``); ``indices``
    (O, J) the points the planner's cost uses.  With ``knn = 0`` every sample belongs to its
    nearest point (trajectory distance, lateral offsets × ``lateral_scale`` as in the selection's
    kernel); with ``knn > 0`` point j's cluster is its ``knn`` nearest samples (for methods that
    plan on all samples).  ``eps`` the coverage risk (z = Φ⁻¹(1 − eps)), ``prior`` the shrinkage
    pseudo-count.  ``bandwidth`` > 0 adds ``h = bandwidth · 1.06 σ_s(k) n^(-1/5)`` (Silverman's
    rule; σ_s(k) the spread of all n samples' arc length at step k) in quadrature to every
    longitudinal spread: the Gaussian of each cluster convolved with the kernel of a density
    estimate, so the margin of the extreme points extends past the extreme samples (a cluster of
    a few samples of a rare intent understates that intent's tail; docs/experiments/frontier.md).
    NumPy: the distances are O(O·J·n·K) (one matrix product), the cluster sums O(O·n·K)
    (O·J·knn·K with ``knn``: sparse membership).  ``data``: :func:`coverage_data` of these
    samples for this ``lateral_scale``, when already computed (the result is the same).
    ``pool`` (O, R), with ``knn > 0``: point j's cluster is the point itself and its ``knn``
    nearest among the samples ``pool`` only (a random subset of the n: the same neighbourhood
    with R/n of its members, for R/n of the work; the caller scales ``knn`` by R/n).  ``data``
    formed from ``rows`` (:func:`coverage_data`) is such a pool for every point set: the samples
    are then those rows and the points themselves (with ``knn = 0`` every row joins its nearest
    point; with ``knn > 0`` the neighbourhoods are among the rows), and ``pool`` must be
    ``None``.
    """
    if data is None:
        data = coverage_data(obstacles_frenet, lateral_scale)
    elif not isinstance(data, CoverageData):
        raise ValueError(f"data must be a CoverageData, got {type(data).__name__}")
    elif data.lateral_scale != float(lateral_scale) or data.shape != np.shape(obstacles_frenet):
        raise ValueError(
            f"data was computed for samples of shape {data.shape} and lateral_scale "
            f"{data.lateral_scale:g}, not {np.shape(obstacles_frenet)} and {float(lateral_scale):g}"
        )
    idx = np.asarray(indices)
    O, n, K, _ = data.shape
    if idx.ndim != 2 or idx.shape[0] != O or idx.shape[1] == 0:
        raise ValueError(f"indices must have shape (O, J) = ({O}, J >= 1), got {idx.shape}")
    if not np.issubdtype(idx.dtype, np.integer) or idx.min() < 0 or idx.max() >= n:
        raise ValueError(f"indices must be integers in [0, {n})")
    z = risk_z(eps)
    prior = float(prior)
    if not (math.isfinite(prior) and prior >= 0):
        raise ValueError(f"prior must be >= 0, got {prior}")
    if isinstance(knn, bool) or not isinstance(knn, int | np.integer) or knn < 0:
        raise ValueError(f"knn must be an integer >= 0, got {knn!r}")
    bandwidth = float(bandwidth)
    if not (math.isfinite(bandwidth) and bandwidth >= 0):
        raise ValueError(f"bandwidth must be finite and >= 0, got {bandwidth}")
    J = idx.shape[1]
    cand = _check_pool(pool, O, n, knn)
    if cand is not None and data.rows is not None:
        raise ValueError("pool and data formed from rows exclude each other (the rows are one)")
    out = np.empty((3, O, J, K))
    X = np.asarray(obstacles_frenet)
    scale2 = np.tile(np.array([1.0, float(lateral_scale) ** 2]), K)
    for o in range(O):  # O is a handful of obstacles; everything inside is vectorised
        h_e = 0.0
        if bandwidth > 0:  # kernel-density smoothing of the tail (Silverman's rule, per step)
            h_e = bandwidth * 1.06 * data.std_s[o] * n**-0.2  # (K,)
        if data.rows is not None:
            anchors = np.asarray(X[o, idx[o]], np.float64).reshape(J, -1) - data.centre[o]
            out[:, o] = _rows_margins(data, o, anchors, lateral_scale, knn, z, prior, h_e)
            continue
        flat, FF = data.flat[o], data.FF[o]
        A = flat[idx[o]]
        among = None if cand is None else cand[o]
        AA = FF[idx[o]]
        F = flat if among is None else flat[among]  # distances to the pool's samples only
        FF = FF if among is None else FF[among]
        # the distances with the lateral offsets × lateral_scale (the selection's kernel)
        sq = AA[:, None] + FF[None, :] - 2.0 * (A * scale2) @ F.T  # (J, n) or (J, R)
        if knn == 0:
            # nearest point of every sample (a repeated point's samples go to its first copy),
            # and every point belongs to its own cluster
            first = _first_copies(A)
            rows = np.concatenate([first[np.argmin(sq[first], axis=0)], np.arange(J)])
            cols = np.concatenate([np.arange(n), idx[o]])
        else:
            k = min(int(knn), sq.shape[1])
            nb = np.argpartition(sq, k - 1, axis=1)[:, :k]  # (J, k) incl. the point itself
            rows, cols = np.repeat(np.arange(J), k), nb.reshape(-1)
            if among is not None:  # pool positions to sample indices, and the point itself
                rows = np.concatenate([rows, np.arange(J)])
                cols = np.concatenate([among[cols], idx[o]])
        # cluster membership, 0/1 (a pair named twice, a point in its own cluster, counts once)
        M = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(J, n)).tocsr()
        M.data[:] = 1.0
        out[:, o] = _cluster_margins(flat, data.flat2[o], idx[o], M, z, prior, h_e)
    return out


def _first_copies(points: np.ndarray) -> np.ndarray:
    """Positions of the first copy of each distinct row of ``points`` (J, 2K), ascending.  A
    point repeated (the same sample named twice, or two samples of equal coordinates) ties in
    every distance, and which copy a matrix product's rounding makes the nearer depends on the
    BLAS: its members go to the first copy instead, on every machine."""
    _, first = np.unique(points, axis=0, return_index=True)
    return np.sort(first)


def _rows_margins(data, o, anchors, lateral_scale, knn, z, prior, h_e):
    """:func:`coverage_margins` of obstacle ``o`` from data formed from rows: the samples are the
    R rows and the J points themselves (``anchors`` (J, 2K), centred as the rows); with
    ``knn = 0`` every row and every point joins its nearest point (a repeated point's members go
    to its first copy), with ``knn > 0`` a point's cluster is its ``knn`` nearest rows; every
    point is in its own cluster.  The rows' part of the moments is a sparse product, the points'
    a (J, J) one: nothing of the rows' size is copied."""
    J = anchors.shape[0]
    K2 = anchors.shape[1]
    scale2 = np.tile(np.array([1.0, float(lateral_scale) ** 2]), K2 // 2)
    ga = anchors * scale2
    gg = (ga * anchors).sum(1)
    sq = gg[:, None] + data.FF[o][None, :] - 2.0 * ga @ data.flat[o].T  # (J, R)
    R = sq.shape[1]
    own = np.eye(J)
    if knn == 0:
        first = _first_copies(anchors)
        rr = np.concatenate([first[np.argmin(sq[first], axis=0)]])
        cc = np.arange(R)
        sqa = gg[:, None] + gg[None, :] - 2.0 * ga @ anchors.T  # (J, J)
        near = first[np.argmin(sqa[first], axis=0)]  # each point's nearest (first copies)
        own[near, np.arange(J)] = 1.0
    else:
        k = min(int(knn), R)
        nb = np.argpartition(sq, k - 1, axis=1)[:, :k]
        rr, cc = np.repeat(np.arange(J), k), nb.reshape(-1)
    M = sp.coo_matrix((np.ones(rr.size), (rr, cc)), shape=(J, R)).tocsr()
    M.data[:] = 1.0
    c = np.maximum(np.asarray(M.sum(1)).reshape(-1) + own.sum(1), 1.0)[:, None]
    mean = (M @ data.flat[o] + own @ anchors) / c
    mu = mean - anchors  # mean deviation from the anchor
    v = np.maximum((M @ data.flat2[o] + own @ (anchors * anchors)) / c - mean * mean, 0.0)
    return _margins_from_moments(c, mu[:, 0::2], mu[:, 1::2], v[:, 0::2], v[:, 1::2], z, prior, h_e)


def _check_pool(pool, O: int, n: int, knn: int) -> np.ndarray | None:
    if pool is None:
        return None
    p = np.asarray(pool)
    if knn == 0:
        raise ValueError("pool needs knn > 0 (with knn = 0 every sample is assigned a point)")
    if p.ndim != 2 or p.shape[0] != O or p.shape[1] == 0:
        raise ValueError(f"pool must have shape (O, R) = ({O}, R >= 1), got {p.shape}")
    if not np.issubdtype(p.dtype, np.integer) or p.min() < 0 or p.max() >= n:
        raise ValueError(f"pool must be integers in [0, {n})")
    return p


# ------------------------------------------------------------------------- what samples support
#: confidence of :attr:`mmdopt.Plan.risk_bound` and of the risk floor
RISK_CONFIDENCE = 0.95


def _check_counts(collisions, n) -> tuple[np.ndarray, np.ndarray]:
    k = np.atleast_1d(np.asarray(collisions))
    m = np.atleast_1d(np.asarray(n))
    if k.shape != m.shape or k.ndim != 1 or k.size == 0:
        raise ValueError(
            f"collisions and n must be 1-D of equal length (one per obstacle), got {k.shape} "
            f"and {m.shape}"
        )
    if not (np.all(m >= 1) and np.all(k >= 0) and np.all(k <= m)):
        raise ValueError(f"need 0 <= collisions <= n and n >= 1, got {k.tolist()}, {m.tolist()}")
    return k.astype(int), m.astype(int)


def clopper_pearson_upper(k: int, n: int, confidence: float = RISK_CONFIDENCE) -> float:
    """One-sided Clopper–Pearson upper bound on a probability seen ``k`` times in ``n``
    independent trials, at ``confidence``: the ``confidence`` quantile of Beta(k + 1, n − k)
    (``1 − (1 − confidence)^(1/n)`` when ``k = 0``)."""
    from scipy.stats import beta

    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if k >= n:
        return 1.0
    if k == 0:
        return float(-np.expm1(np.log1p(-confidence) / n))
    return float(beta.ppf(confidence, k + 1, n - k))


def risk_bound(collisions, n, confidence: float = RISK_CONFIDENCE) -> float:
    """Upper bound, at ``confidence``, on the probability that a plan meets any obstacle, from
    the ``collisions[g]`` of ``n[g]`` planning samples of each of G groups that it meets.

    **Joint futures** (G = 1, what :func:`mmdopt.plan` uses by default,
    ``SafetyConfig.joint_futures``): sample i of every obstacle is one draw of the scene's
    joint future, ``collisions = [k]`` counts the draws the plan meets with any obstacle, and
    the bound is Clopper–Pearson on k of n.  **Separate draws** (G = O, one group per
    obstacle): each obstacle's probability is bounded by Clopper–Pearson at
    ``1 − (1 − confidence)/O`` and the bounds are summed (the union bound, with the confidence
    split by Bonferroni), capped at 1; valid whatever the obstacles' dependence, and looser.
    Assumptions: the draws are independent, from the predictor's distribution of the future,
    and the plan is judged as a fixed trajectory.  A plan optimised
    against the same samples is not independent of them, so the bound is optimistic by the
    plan's dependence on the few samples that shape it (scenario theory's support samples);
    validation futures drawn afresh measure the rate without that caveat."""
    k, m = _check_counts(collisions, n)
    c = 1.0 - (1.0 - confidence) / k.size
    return float(
        min(1.0, sum(clopper_pearson_upper(int(a), int(b), c) for a, b in zip(k, m, strict=True)))
    )


def risk_floor(n, confidence: float = RISK_CONFIDENCE) -> float:
    """The least :func:`risk_bound` ``n`` samples per obstacle can give: that of a plan that
    meets none of them.  A request below it cannot be confirmed by these samples."""
    m = np.atleast_1d(np.asarray(n))
    return risk_bound(np.zeros_like(m), m, confidence)


def _check_int(v, name: str, least: int) -> None:
    """``ValueError`` naming ``name`` unless ``v`` is an int (not a bool) >= ``least``."""
    if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < least:
        raise ValueError(f"{name} must be an int >= {least}, got {v!r}")


def samples_for_risk(
    eps: float, obstacles: int = 1, confidence: float = RISK_CONFIDENCE, hits: int = 0
) -> int:
    """n(ε): the fewest samples per obstacle for which a plan that meets ``hits`` of each
    group's samples still has :func:`risk_bound` ≤ ``eps`` with ``obstacles`` groups (1 for
    joint futures, whatever the number of obstacles; O for separate draws).

    ``hits = 0`` gives the fewest that can confirm ε at all (:func:`risk_floor` ≤ ε),
    ``⌈ln(δ/G) / ln(1 − ε/G)⌉`` with δ = 1 − confidence and G = ``obstacles`` (about 3·G/ε at
    95 %): a plan must then clear every sample.  More hits ask for more samples (about 6.3·G/ε
    for 2, 10.5·G/ε for 5, 19.4·G/ε for 12, 52·G/ε for 40) and let a plan come as close to
    its budget as the samples show it does."""
    eps = check_risk(eps, "eps")
    _check_int(obstacles, "obstacles", 1)
    _check_int(hits, "hits", 0)
    d = (1.0 - confidence) / obstacles
    n0 = int(math.ceil(math.log(d) / math.log1p(-eps / obstacles)))
    if hits == 0:
        return n0
    c, target = 1.0 - d, eps / obstacles
    lo, hi = max(n0, int(hits) + 1), max(n0, int(hits) + 1)
    while clopper_pearson_upper(int(hits), hi, c) > target:  # the bound falls with n
        lo, hi = hi, 2 * hi
    while lo < hi:
        mid = (lo + hi) // 2
        if clopper_pearson_upper(int(hits), mid, c) <= target:
            hi = mid
        else:
            lo = mid + 1
    return hi


def hits_for_risk(
    eps: float, n: int, obstacles: int = 1, confidence: float = RISK_CONFIDENCE
) -> int:
    """The most of its ``n`` samples per group a plan may meet (the same count for each of
    ``obstacles`` groups: 1 for joint futures, O for separate draws) while its
    :func:`risk_bound` stays ≤ ``eps``; −1 when even a plan that meets none has a bound above
    ``eps`` (``n`` is below :func:`samples_for_risk`)."""
    eps = check_risk(eps, "eps")
    _check_int(obstacles, "obstacles", 1)
    _check_int(n, "n", 1)
    c, target = 1.0 - (1.0 - confidence) / obstacles, eps / obstacles
    if clopper_pearson_upper(0, int(n), c) > target:
        return -1
    lo, hi = 0, int(n)  # the bound rises with k: the largest k with bound <= target
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if clopper_pearson_upper(mid, int(n), c) <= target:
            lo = mid
        else:
            hi = mid - 1
    return lo
