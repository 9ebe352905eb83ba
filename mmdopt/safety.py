"""A last line of defence for any planner: the longitudinal safe distance of
Responsibility-Sensitive Safety (RSS; Shalev-Shwartz, Shammah and Shashua, "On a formal model of
safe and scalable self-driving cars", 2017, Definition 1) checked on every plan before it is
executed, with a braking fallback that is itself checked.

::

    from mmdopt.safety import RSSConfig, shield

    plan, record = shield(plan, road.path, obstacles, RSSConfig(), executed=0.5)
    record.intervened, record.reason, record.rule

**The rule.**  A front car at speed ``v_f`` may brake at up to ``b_max``; the ego (the rear car)
reacts after a response time ρ, accelerating at up to ``a_max`` meanwhile, and then brakes at
least at ``b_min``.  The gap between them must be at least (:func:`rss_safe_distance`)

    d_min = [v_r ρ + ½ a_max ρ² + (v_r + ρ a_max)² / (2 b_min) − v_f² / (2 b_max)]₊ .

**The check** (:func:`check_plan`) applies the same worst case to the plan that is about to run:
the ego executes the plan for ``executed`` seconds (the receding-horizon step δ: the next
chance to react) and then brakes at ``b_min`` to a stop at the lateral offset it has reached;
every obstacle ahead whose lateral offset overlaps the ego's corridor brakes at ``b_max`` from its
current position and speed.  The plan passes when the longitudinal centre-to-centre distance
stays at least ``contact + margin`` until both have stopped.  With the plan's own accelerations
in place of the bound ``a_max`` during ρ = ``executed``, this is RSS's condition for that plan
(a plan that accelerates at ``a_max`` passes exactly when the gap is at least ``d_min`` plus the
contact distance).  **The fallback** first keeps the plan's lateral path and brakes gently,
at ``b_gentle`` and up to ``b_min`` in five steps; such a fallback is checked exactly as a plan
is (``executed`` seconds of it, then ``b_min``), so it carries the same guarantee.  When none
passes, :func:`braking_plan` holds the current lateral offset and brakes at ``b_min`` (then
harder, up to ``b_emergency``) from now; it is checked with the same rule along its own
profile.  The gentlest braking that passes is used.  With
``RSSConfig.lateral_accel > 0`` and the road's lane centres, at each braking level a fallback
that finishes the move to a lane centre while it brakes (:func:`lane_braking_plan`) is tried
first; it is checked against every car ahead that its lateral path comes near, so after any
part of it the fallback that holds the offset reached, braking as hard, passes again.

**What it guarantees.**  Suppose the first state passes the fallback check, every obstacle in
the corridor brakes at most at ``b_max`` and does not change its lateral offset, the obstacle
states are exact and the ego executes its plans to within ``margin``.  Then no rear-end collision
with those obstacles happens: a plan runs only if the check passed, so at the next replan the
braking fallback (the continuation the check assumed) passes again, by induction.  Not covered:
an obstacle that cuts into the corridor closer than the safe distance (RSS assigns that to the
car cutting in), obstacles behind or beside the ego (including a faster car behind in a lane the
ego changes into, which RSS would make the ego responsible for), obstacles braking harder than
``b_max`` (a crashed car), and lateral safety unless the lateral rule below is on.

**Two more rules**, each checked only when its inputs are given, on the plan and on every
fallback alike.  *Lateral* (``RSSConfig.lateral`` and the cars' lateral states): RSS's lateral
safe distance (Definition 4, :func:`rss_lateral_safe_distance`) between the ego and each car
beside it, over the part of the plan that runs (:func:`check_lateral`).  *Crossing* (the conflict
areas of crossing routes at a junction, :func:`check_crossings`): where another car may reach
the area before the ego, braking at ``b_min`` after the step, could have stopped, the ego must
be able to stop before it, unless it is already too close to stop even at ``b_emergency`` (then
RSS's response is to clear the area).  :attr:`ShieldRecord.rule` says which rule a replaced plan
failed first.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

import frenet

from .plans import Plan, PlanStatus, replacement_plan

__all__ = [
    "RSSConfig",
    "PlanCheck",
    "ShieldRecord",
    "rss_safe_distance",
    "rss_lateral_safe_distance",
    "obstacle_states_from_samples",
    "obstacle_states_from_cartesian",
    "check_plan",
    "check_lateral",
    "check_crossings",
    "braking_plan",
    "lane_braking_plan",
    "shield",
]


@dataclass(frozen=True)
class RSSConfig:
    """Parameters of the RSS longitudinal rule and of the shield (SI units).

    response_time : ρ of :func:`rss_safe_distance` (s)
    a_max : the ego's largest acceleration during ρ in :func:`rss_safe_distance` (m/s²)
    b_min : the braking the ego is guaranteed to apply after ρ (m/s², > 0)
    b_max : the hardest braking of a front car (m/s², ≥ ``b_min`` in RSS's usual setting)
    b_emergency : the hardest braking the fallback may use when ``b_min`` does not pass (m/s²,
        ≥ ``b_min``)
    contact : longitudinal centre-to-centre distance at which two cars touch (m; a car length)
    margin : extra gap for tracking and state errors (m, ≥ 0)
    lateral_overlap : an obstacle is in the ego's corridor when its lateral offset is closer
        than this to the ego's (m; the car width plus a lateral margin)
    lateral_accel : 0 (default): the fallback holds the lateral offset; > 0 (m/s²): given lane
        centres, a fallback may also brake while it finishes the move to a lane centre at up to
        this lateral acceleration (:func:`lane_braking_plan`), checked against every car ahead
        whose offset comes within ``lateral_overlap`` of its lateral path
    b_gentle : the gentlest braking the shield tries (m/s², in (0, ``b_min``]; 1 by default).
        Below ``b_min`` a fallback keeps the plan's lateral profile, brakes at the level tried
        and is checked exactly as a plan is (``executed`` seconds of it, then ``b_min``), so it
        carries the same guarantee; ``b_gentle = b_min`` turns these levels off
    lateral : check RSS's lateral safe distance (:func:`check_lateral`) to the cars beside the
        ego as well, when the shield is given their lateral states (``False`` by default)
    lat_response_time : ρ_lat of :func:`rss_lateral_safe_distance` (s)
    lat_a_max : the largest lateral acceleration of either car towards the other during ρ_lat
        (m/s²)
    lat_b_min : the least lateral braking of either car after ρ_lat (m/s², > 0)
    lat_mu : the lateral fluctuation margin μ of Definition 4 (m)
    width : a car's width: the lateral centre-to-centre distance at which two cars touch (m)
    """

    response_time: float = 0.5
    a_max: float = 3.0
    b_min: float = 6.0
    b_max: float = 6.0
    b_emergency: float = 8.0
    contact: float = 5.0
    margin: float = 1.0
    lateral_overlap: float = 2.5
    lateral_accel: float = 0.0
    b_gentle: float = 1.0
    lateral: bool = False
    lat_response_time: float = 0.5
    lat_a_max: float = 1.0
    lat_b_min: float = 1.5
    lat_mu: float = 0.3
    width: float = 2.0

    def __post_init__(self) -> None:
        if not isinstance(self.lateral, bool):
            raise ValueError(f"RSSConfig.lateral must be a bool, got {self.lateral!r}")
        nonneg = ("response_time", "a_max", "margin", "lateral_accel")
        for name in (*nonneg, "lat_response_time", "lat_a_max", "lat_mu"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"RSSConfig.{name} must be a finite number >= 0, got {v!r}")
        positive = ("b_min", "b_max", "b_emergency", "contact", "lateral_overlap", "b_gentle")
        for name in (*positive, "lat_b_min", "width"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"RSSConfig.{name} must be a finite number > 0, got {v!r}")
        if self.b_emergency < self.b_min:
            raise ValueError(
                f"RSSConfig.b_emergency ({self.b_emergency}) must be >= b_min ({self.b_min})"
            )
        if self.b_gentle > self.b_min:
            raise ValueError(
                f"RSSConfig.b_gentle ({self.b_gentle}) must be <= b_min ({self.b_min})"
            )


@dataclass(frozen=True)
class PlanCheck:
    """The result of :func:`check_plan` (and of :func:`check_lateral` and
    :func:`check_crossings`, which say what their fields mean for their rules).

    safe : every obstacle in the corridor keeps the required gap
    margin : the least (gap − contact − margin) over the checked obstacles and times (m; +inf
        when no obstacle is in the corridor ahead); negative when unsafe
    obstacle : index of the obstacle that sets ``margin`` (−1: none)
    time : when that least gap occurs (s from now)
    n_checked : obstacles in the corridor ahead
    """

    safe: bool
    margin: float
    obstacle: int
    time: float
    n_checked: int


@dataclass(frozen=True)
class ShieldRecord:
    """What :func:`shield` did with one plan (JSON-friendly scalars).

    intervened : the plan was replaced by a braking fallback
    reason : why (empty when the plan passed)
    plan_margin : :attr:`PlanCheck.margin` of the planner's plan (m): of the rule that failed
        when intervened, else the least over the rules checked
    fallback_decel : the fallback's braking (m/s²; 0 when not intervened)
    fallback_safe : the fallback passed the check (``False``: even ``b_emergency`` does not; the
        hardest braking is used)
    n_checked : :attr:`PlanCheck.n_checked` of the rule that failed when intervened, else of
        the longitudinal rule (obstacles in the corridor ahead)
    rule : the rule the plan failed first: ``"longitudinal"`` (:func:`check_plan`),
        ``"lateral"`` (:func:`check_lateral`) or ``"crossing"`` (:func:`check_crossings`);
        ``""`` when the plan passed
    """

    intervened: bool
    reason: str
    plan_margin: float
    fallback_decel: float
    fallback_safe: bool
    n_checked: int
    rule: str = ""


# ------------------------------------------------------------------------------------ the rule
def rss_safe_distance(v_rear, v_front, config: RSSConfig | None = None):
    """RSS's longitudinal safe distance (m) between a rear car at ``v_rear`` and a front car at
    ``v_front`` (m/s, ≥ 0; arrays broadcast), Definition 1 of Shalev-Shwartz et al. (2017):
    ``[v_r ρ + ½ a_max ρ² + (v_r + ρ a_max)²/(2 b_min) − v_f²/(2 b_max)]₊``.  The gap is between
    the rear car's front and the front car's rear."""
    c = RSSConfig() if config is None else config
    if not isinstance(c, RSSConfig):
        raise ValueError(f"config must be an RSSConfig, got {type(c).__name__}")
    vr = np.asarray(v_rear, dtype=np.float64)
    vf = np.asarray(v_front, dtype=np.float64)
    if not (np.all(np.isfinite(vr)) and np.all(vr >= 0)):
        raise ValueError("v_rear must be finite and >= 0")
    if not (np.all(np.isfinite(vf)) and np.all(vf >= 0)):
        raise ValueError("v_front must be finite and >= 0")
    rho, a = c.response_time, c.a_max
    d = (
        vr * rho
        + 0.5 * a * rho**2
        + (vr + rho * a) ** 2 / (2.0 * c.b_min)
        - vf**2 / (2.0 * c.b_max)
    )
    out = np.maximum(d, 0.0)
    return float(out) if out.ndim == 0 else out


def rss_lateral_safe_distance(v_left, v_right, config: RSSConfig | None = None):
    """RSS's lateral safe distance (m) between a car on the left and a car on the right,
    Definition 4 of Shalev-Shwartz et al. (2017).  The lateral velocities ``v_left`` and
    ``v_right`` (m/s; arrays broadcast) are both measured along one direction, pointing from
    the left car towards the right car: a positive ``v_left`` closes the gap, a positive
    ``v_right`` opens it.  In the worst case each car accelerates towards the other at
    ``lat_a_max`` for ρ = ``lat_response_time`` and then brakes laterally at ``lat_b_min`` to a
    lateral stop; with ``v1ρ = v_left + ρ a`` and ``v2ρ = v_right − ρ a``,

        d = μ + [(v_left + v1ρ)/2·ρ + v1ρ|v1ρ|/(2 b) − ((v_right + v2ρ)/2·ρ + v2ρ|v2ρ|/(2 b))]₊ .

    Each bracketed part is the signed lateral distance a car covers until it stops moving
    sideways.  The paper writes the braking terms as ``+v1ρ²/(2b)`` and ``−v2ρ²/(2b)``, which
    hold while each car moves towards the other (``v1ρ ≥ 0``, ``v2ρ ≤ 0``); ``v|v|`` keeps the
    sign otherwise, so a car moving away counts as moving away rather than closer.  The result
    is symmetric: swapping the cars and reversing the direction,
    ``d(v_left, v_right) = d(−v_right, −v_left)``.  The gap is between the cars' sides (the
    centre-to-centre lateral distance minus ``width``).  ``μ`` = ``lat_mu``."""
    c = RSSConfig() if config is None else config
    if not isinstance(c, RSSConfig):
        raise ValueError(f"config must be an RSSConfig, got {type(c).__name__}")
    v1 = np.asarray(v_left, dtype=np.float64)
    v2 = np.asarray(v_right, dtype=np.float64)
    if not np.all(np.isfinite(v1)):
        raise ValueError("v_left must be finite")
    if not np.all(np.isfinite(v2)):
        raise ValueError("v_right must be finite")
    rho, a, b = c.lat_response_time, c.lat_a_max, c.lat_b_min
    v1r, v2r = v1 + rho * a, v2 - rho * a
    left = 0.5 * (v1 + v1r) * rho + v1r * np.abs(v1r) / (2.0 * b)
    right = 0.5 * (v2 + v2r) * rho + v2r * np.abs(v2r) / (2.0 * b)
    out = c.lat_mu + np.maximum(left - right, 0.0)
    return float(out) if out.ndim == 0 else out


# ------------------------------------------------------------------------- obstacles' states
def obstacle_states_from_samples(path: frenet.ReferencePath, obstacles, t) -> np.ndarray:
    """Current Frenet states ``(O, 3)`` = ``(s, d, ṡ)`` of obstacles from prediction samples
    ``(O, n, K, 2)`` on the grid ``t`` (K,): the mean position at ``t[0]`` and the slowest
    sample's speed along the path over ``[t[0], t[1]]`` (the lower speed is the cautious one for
    a car ahead).  Speeds are clipped at 0."""
    arr = np.asarray(obstacles, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if arr.ndim != 4 or arr.shape[-1] != 2 or arr.shape[1] < 1:
        raise ValueError(f"obstacles must have shape (O, n, K, 2), got {arr.shape}")
    if t.ndim != 1 or t.shape[0] != arr.shape[2] or t.shape[0] < 2 or not t[1] > t[0]:
        raise ValueError(f"t must be an increasing (K,) grid with K = {arr.shape[2]} >= 2")
    if arr.shape[0] == 0:
        return np.zeros((0, 3))
    s0, d0 = path.to_frenet(arr[:, :, 0, 0], arr[:, :, 0, 1])
    s1, _ = path.to_frenet(arr[:, :, 1, 0], arr[:, :, 1, 1])
    v = np.min((s1 - s0) / (t[1] - t[0]), axis=1)
    return np.stack([s0.mean(axis=1), d0.mean(axis=1), np.maximum(v, 0.0)], axis=-1)


def obstacle_states_from_cartesian(
    path: frenet.ReferencePath, states, *, lateral: bool = False
) -> np.ndarray:
    """Frenet states ``(O, 3)`` = ``(s, d, ṡ)`` from Cartesian ``(O, 4)`` = ``(x, y, vx, vy)``
    (the velocity projected on the path's tangent, ``ṡ = v·t̂ / (1 − dκ)``, clipped at 0).
    With ``lateral=True``: ``(O, 4)`` = ``(s, d, ṡ, ḋ)``, adding the lateral velocity
    ``ḋ = v·n̂`` on the path's left normal ``n̂`` (not clipped; > 0 moving left), the input of
    :func:`check_lateral`."""
    if not isinstance(lateral, bool):
        raise ValueError(f"lateral must be a bool, got {lateral!r}")
    st = np.asarray(states, dtype=np.float64)
    if st.ndim != 2 or st.shape[1] != 4 or not np.all(np.isfinite(st)):
        raise ValueError(f"states must be a finite (O, 4) array (x, y, vx, vy), got {st.shape}")
    if st.shape[0] == 0:
        return np.zeros((0, 4 if lateral else 3))
    s, d = path.to_frenet(st[:, 0], st[:, 1])
    th = path.heading(s)
    one = np.maximum(1.0 - d * path.curvature(s), 1e-6)
    vs = (st[:, 2] * np.cos(th) + st[:, 3] * np.sin(th)) / one
    if not lateral:
        return np.stack([s, d, np.maximum(vs, 0.0)], axis=-1)
    vd = -st[:, 2] * np.sin(th) + st[:, 3] * np.cos(th)
    return np.stack([s, d, np.maximum(vs, 0.0), vd], axis=-1)


# ----------------------------------------------------------------------------------- the check
def _braking(s0, v0, b: float, t: np.ndarray) -> np.ndarray:
    """Position along the path of a car braking at ``b`` from ``(s0, v0)`` until it stops
    (``s0``, ``v0`` and ``t`` broadcast against each other)."""
    v0 = np.maximum(v0, 0.0)
    tt = np.minimum(t, v0 / b)
    return s0 + v0 * tt - 0.5 * b * tt**2


def check_plan(
    t,
    s,
    d,
    vs,
    obstacles: np.ndarray,
    config: RSSConfig | None = None,
    *,
    executed: float,
) -> PlanCheck:
    """Check a plan ``(t, s, d, ṡ)`` (K,) in the Frenet frame against RSS's longitudinal rule.

    The ego follows the plan for ``executed`` seconds (0: not at all), then brakes at
    ``config.b_min`` to a stop at the lateral offset reached; each obstacle of ``obstacles``
    ``(O, 3)`` = current ``(s, d, ṡ)`` that is ahead (``s > s(0)``) and in the corridor (its
    offset closer than ``lateral_overlap`` to the plan's over ``[0, executed]``) brakes at
    ``config.b_max`` from now.  A fallback is checked with ``executed`` its whole horizon: the
    ego follows its braking (and lateral) profile throughout.  Safe when the distance along the
    path stays ``≥ contact + margin`` until both have stopped (the distance is concave while both
    brake, so it is checked on a 20 ms grid plus the instants where a phase ends).
    """
    c = RSSConfig() if config is None else config
    if not isinstance(c, RSSConfig):
        raise ValueError(f"config must be an RSSConfig, got {type(c).__name__}")
    t, s, d, vs = (np.asarray(a, dtype=np.float64) for a in (t, s, d, vs))
    if t.ndim != 1 or t.shape[0] < 2 or any(a.shape != t.shape for a in (s, d, vs)):
        raise ValueError("t, s, d, vs must be (K,) arrays of one length K >= 2")
    if not all(np.all(np.isfinite(a)) for a in (t, s, d, vs)):
        raise ValueError("t, s, d, vs must be finite")
    ob = np.asarray(obstacles, dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(ob)):
        raise ValueError("obstacles must be a finite (O, 3) array of (s, d, vs)")
    ex = float(executed)
    if not (math.isfinite(ex) and 0.0 <= ex <= t[-1] - t[0]):
        raise ValueError(f"executed must be in [0, {t[-1] - t[0]:g}] s, got {executed!r}")
    tp = t - t[0]
    d_ex = np.append(d[tp <= ex], np.interp(ex, tp, d))
    s_ex, v_ex = float(np.interp(ex, tp, s)), max(float(np.interp(ex, tp, vs)), 0.0)
    ahead = ob[:, 0] > s[0]
    lateral = np.min(np.abs(ob[:, 1][:, None] - d_ex[None, :]), axis=1)
    idx = np.flatnonzero(ahead & (lateral < c.lateral_overlap))
    if idx.size == 0:
        return PlanCheck(True, math.inf, -1, 0.0, 0)
    t_stop = ex + v_ex / c.b_min
    t_front = ob[idx, 2] / c.b_max
    t_end = max(t_stop, float(np.max(t_front))) + 1e-3
    tc = np.unique(np.concatenate([np.arange(0.0, t_end, 0.02), [ex, t_stop, t_end], t_front]))
    tc = tc[tc <= t_end]
    ego = np.where(
        tc <= ex, np.interp(tc, tp, s), _braking(s_ex, v_ex, c.b_min, np.maximum(tc - ex, 0.0))
    )
    need = c.contact + c.margin
    # every corridor obstacle braking at b_max from now, (len(idx), T), all at once
    gap = _braking(ob[idx, 0][:, None], ob[idx, 2][:, None], c.b_max, tc[None, :])
    gap = gap - ego[None, :] - need
    i, k = np.unravel_index(int(np.argmin(gap)), gap.shape)
    least = float(gap[i, k])
    return PlanCheck(least >= 0.0, least, int(idx[i]), float(tc[k]), int(idx.size))


def _config(config) -> RSSConfig:
    """``config`` (``None``: the defaults) as an :class:`RSSConfig`, or a ValueError."""
    c = RSSConfig() if config is None else config
    if not isinstance(c, RSSConfig):
        raise ValueError(f"config must be an RSSConfig, got {type(c).__name__}")
    return c


def _profile(names: str, *arrays) -> tuple[np.ndarray, ...]:
    """``arrays`` as float (K,) arrays of one length K ≥ 2, finite, or a ValueError naming
    them (``names``: "t, s, d, vd")."""
    out = tuple(np.asarray(a, dtype=np.float64) for a in arrays)
    t = out[0]
    if t.ndim != 1 or t.shape[0] < 2 or any(a.shape != t.shape for a in out):
        raise ValueError(f"{names} must be (K,) arrays of one length K >= 2")
    if not all(np.all(np.isfinite(a)) for a in out):
        raise ValueError(f"{names} must be finite")
    if not np.all(np.diff(t) > 0):
        raise ValueError("t must be increasing")
    return out


def _executed(executed, tp: np.ndarray) -> float:
    """``executed`` as seconds in ``[0, tp[-1]]``, or a ValueError naming it."""
    ex = float(executed)
    if not (math.isfinite(ex) and 0.0 <= ex <= tp[-1]):
        raise ValueError(f"executed must be in [0, {tp[-1]:g}] s, got {executed!r}")
    return ex


def _finite_rows(values, name: str, fields: str) -> np.ndarray:
    """``values`` as a finite ``(N, len(fields))`` array (empty: ``(0, k)``), or a ValueError
    naming it ``name`` and its columns ``fields`` (comma-separated)."""
    k = len(fields.split(","))
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, k))
    if arr.ndim != 2 or arr.shape[1] != k or not np.all(np.isfinite(arr)):
        raise ValueError(
            f"{name} must be a finite (N, {k}) array of ({fields}), got shape {arr.shape}"
        )
    return arr


def _lateral_states(obstacles, name: str) -> np.ndarray:
    """``obstacles`` as a finite ``(O, 4)`` array, or a ValueError naming it ``name``."""
    return _finite_rows(obstacles, name, "s, d, vs, vd")


#: a car moving sideways faster than this times its speed along the ego's path (a heading more
#: than 27° off the path) crosses the path rather than running beside it: not
#: :func:`check_lateral`'s (a junction's crossing traffic, :func:`check_crossings`)
PARALLEL = 0.5


def check_lateral(
    t,
    s,
    d,
    vd,
    obstacles: np.ndarray,
    config: RSSConfig | None = None,
    *,
    executed: float,
) -> PlanCheck:
    """Check a plan ``(t, s, d, ḋ)`` (K,) in the Frenet frame against RSS's lateral rule
    (Shalev-Shwartz et al. 2017, Definition 4: :func:`rss_lateral_safe_distance`) for the cars
    beside the ego.

    ``obstacles`` ``(O, 4)`` = current ``(s, d, ṡ, ḋ)``
    (:func:`obstacle_states_from_cartesian` with ``lateral=True``); each is assumed to keep
    ``ṡ`` and ``ḋ`` over the check.  A car is *beside* the ego when it overlaps the ego
    longitudinally (centre-to-centre distance along the path below ``contact``, or the two
    passing each other) at some time in ``[0, executed]``, and is not in the ego's
    longitudinal corridor now (``|d_ob − d(0)| ≥ lateral_overlap``: the cars ahead in the
    corridor are :func:`check_plan`'s) and runs along the ego's path (``|ḋ| ≤``
    :data:`PARALLEL` ``· max(ṡ, 1 m/s)``: a car crossing it is :func:`check_crossings`'s).  For
    each car beside, at each plan time in ``[0, executed]`` (the plan's grid, plus
    ``executed`` interpolated), the gap between the cars' sides, ``|d_ob(τ) − d(τ)| −
    width``, must be at least the lateral safe distance with both lateral velocities oriented
    from the car on the left (+d) to the one on the right.
    This is checked at all those times, also when the car is longitudinally clear at some of
    them (a cautious reading of "beside").  The lateral velocity the plan reaches is covered by
    the rule itself: it assumes each car may go on towards the other for ρ_lat and then brake
    sideways.  A fallback is checked with ``executed`` its whole horizon.

    ``margin``: the least (gap − required) over the cars beside and the times (m; +inf when no
    car is beside), ``obstacle``/``time``: where it occurs, ``n_checked``: the cars beside; safe
    when ``margin ≥ 0``.
    """
    c = _config(config)
    t, s, d, vd = _profile("t, s, d, vd", t, s, d, vd)
    ob = _lateral_states(obstacles, "obstacles")
    tp = t - t[0]
    ex = _executed(executed, tp)
    tc = np.unique(np.append(tp[tp <= ex], ex))
    s_e, d_e, vd_e = (np.interp(tc, tp, a) for a in (s, d, vd))
    if ob.shape[0] == 0:
        return PlanCheck(True, math.inf, -1, 0.0, 0)
    rel = ob[:, 0][:, None] + ob[:, 2][:, None] * tc[None, :] - s_e[None, :]  # (O, T)
    passing = np.any(np.sign(rel[:, 1:]) * np.sign(rel[:, :-1]) < 0, axis=1)
    overlap = np.any(np.abs(rel) < c.contact, axis=1) | passing
    outside = np.abs(ob[:, 1] - d[0]) >= c.lateral_overlap
    # RSS's lateral rule is for cars on parallel paths: a car crossing the ego's path (at a
    # junction: moving across it faster than PARALLEL times along it) is the crossing rule's
    parallel = np.abs(ob[:, 3]) <= PARALLEL * np.maximum(ob[:, 2], 1.0)
    idx = np.flatnonzero(overlap & outside & parallel)
    if idx.size == 0:
        return PlanCheck(True, math.inf, -1, 0.0, 0)
    d_ob = ob[idx, 1][:, None] + ob[idx, 3][:, None] * tc[None, :]  # (n, T)
    vd_ob = np.broadcast_to(ob[idx, 3][:, None], d_ob.shape)
    vd_ego = np.broadcast_to(vd_e[None, :], d_ob.shape)
    ob_left = d_ob >= d_e[None, :]
    # the direction from the left car to the right one is −d: velocities along it are −ḋ
    v_left = -np.where(ob_left, vd_ob, vd_ego)
    v_right = -np.where(ob_left, vd_ego, vd_ob)
    gap = np.abs(d_ob - d_e[None, :]) - c.width
    slack = gap - rss_lateral_safe_distance(v_left, v_right, c)
    i, k = np.unravel_index(int(np.argmin(slack)), slack.shape)
    least = float(slack[i, k])
    return PlanCheck(least >= 0.0, least, int(idx[i]), float(tc[k]), int(idx.size))


def _crossings(crossings) -> np.ndarray:
    """``crossings`` as a finite ``(C, 3)`` array of ``(s_in, s_out, t_arrive)`` with
    ``s_out ≥ s_in`` and ``t_arrive ≥ 0``, or a ValueError naming it."""
    cr = _finite_rows(crossings, "crossings", "s_in, s_out, t_arrive")
    if not np.all(cr[:, 1] >= cr[:, 0]):
        raise ValueError("crossings must have s_out >= s_in in every row")
    if not np.all(cr[:, 2] >= 0):
        raise ValueError("crossings must have t_arrive >= 0 (s from now) in every row")
    return cr


def check_crossings(
    t,
    s,
    vs,
    crossings: np.ndarray,
    config: RSSConfig | None = None,
    *,
    executed: float,
) -> PlanCheck:
    """Check a plan ``(t, s, ṡ)`` (K,) against the conflict areas of crossing paths (a
    junction), after RSS's treatment of routes of different geometry (Shalev-Shwartz et al.
    2017): a car that may meet another in a conflict area must be able to stop before it.

    ``crossings`` ``(C, 3)`` = ``(s_in, s_out, t_arrive)``: an interval ``[s_in, s_out]`` of arc
    length along the ego's path (positions of the ego's centre, already inflated by both cars'
    half lengths) where another car's predicted route crosses it, and the earliest time
    ``t_arrive`` (s from now) that car could reach it.  The ego follows the plan for
    ``executed`` seconds and then brakes at ``b_min``: it stops at
    ``t_stop = executed + v_ex/b_min``, at ``s_stop = s_ex + v_ex²/(2 b_min)``. A crossing
    *applies* when it is not behind the ego (``s_out > s(0)``) and the ego is not already
    committed to it: braking from now even at ``b_emergency`` ends inside the area, past
    ``s_in`` (an ego at rest never is). A committed ego could only stop inside the conflict
    area; RSS's proper response there is to clear it, not to brake, so the rule does not apply
    (and so the braking fallback of :func:`shield` at ``b_emergency`` passes it whenever it
    stops within the plan's horizon). For every crossing that applies, the plan either stops
    before it (``s_stop ≤ s_in − margin``, or where the ego already is when it waits within the
    margin: it may yield) or clears it ahead of the other car: the plan's centre passes
    ``s_out`` at least ``response_time`` before ``t_arrive`` (it may go first). A plan that
    would enter the area with neither is refused before the ego is committed to it, so the ego
    never stands in a conflict area a car may reach first: the rule carries by induction from
    replan to replan (a plan that goes first stays ahead of ``t_arrive``, which only comes
    nearer by the time that has passed). Not covered: a car arriving earlier than ``t_arrive``
    says (faster than its earliest arrival) and one the ego is committed to when it first
    appears.

    ``margin``: the least ``s_in − margin − s_stop`` over the crossings that apply (m; +inf:
    none), ``obstacle``: that crossing's row, ``time``: its ``t_arrive``, ``n_checked``: the
    crossings that apply; safe when ``margin ≥ 0``.  A fallback is checked with ``executed``
    its whole horizon.
    """
    c = _config(config)
    t, s, vs = _profile("t, s, vs", t, s, vs)
    cr = _crossings(crossings)
    tp = t - t[0]
    ex = _executed(executed, tp)
    if cr.shape[0] == 0:
        return PlanCheck(True, math.inf, -1, 0.0, 0)
    s_ex, v_ex = float(np.interp(ex, tp, s)), max(float(np.interp(ex, tp, vs)), 0.0)
    s_stop = s_ex + v_ex**2 / (2.0 * c.b_min)
    v0 = max(float(vs[0]), 0.0)
    s_in = cr[:, 0] - c.margin
    # committed: even the hardest braking from now ends inside the area (an ego at rest never is)
    committed = s[0] + v0**2 / (2.0 * c.b_emergency) > cr[:, 0]
    idx = np.flatnonzero((cr[:, 1] > s[0]) & ~committed)
    if idx.size == 0:
        return PlanCheck(True, math.inf, -1, 0.0, 0)
    # going first: the time the plan's centre passes s_out (inf when it does not in the horizon)
    s_mono = np.maximum.accumulate(s)
    passed = s_mono[None, :] >= cr[idx, 1][:, None]
    t_clear = np.where(passed.any(axis=1), tp[np.argmax(passed, axis=1)], np.inf)
    first = t_clear <= cr[idx, 2] - c.response_time
    idx = idx[~first]
    if idx.size == 0:
        return PlanCheck(True, math.inf, -1, 0.0, 0)
    # stopping short of the area by the margin, or where the ego already is (waiting in the
    # margin, having crept into it while it tracked a stop)
    slack = np.maximum(s_in[idx], float(s[0])) - s_stop
    i = int(np.argmin(slack))
    least = float(slack[i])
    return PlanCheck(least >= 0.0, least, int(idx[i]), float(cr[idx[i], 2]), int(idx.size))


# -------------------------------------------------------------------------------- the fallback
#: braking levels below ``b_min`` the shield tries, evenly from ``RSSConfig.b_gentle`` up
GENTLE_LEVELS = 5


def braking_plan(
    plan: Plan,
    path: frenet.ReferencePath,
    decel: float,
    *,
    reason: str = "",
    status: PlanStatus = PlanStatus.FALLBACK,
) -> Plan:
    """The braking fallback of ``plan``: from the plan's first state, hold the lateral offset
    and brake at ``decel`` (m/s²) to a stop, on the plan's time grid; a :class:`Plan` with
    ``status`` (FALLBACK; the shield's are SHIELDED), no Algorithm 1 state (the next plan starts
    cold), ``message`` ``reason`` and nothing measured on ``plan`` kept
    (:func:`mmdopt.plans.replacement_plan`)."""
    b = float(decel)
    if not (math.isfinite(b) and b > 0):
        raise ValueError(f"decel must be a finite number > 0, got {decel!r}")
    t = np.asarray(plan.t, dtype=np.float64)
    zero = np.zeros_like(t)
    d = np.full_like(t, float(plan.d[0]))
    return _fallback(plan, path, b, d, zero, zero.copy(), reason, status)


def _fallback(plan: Plan, path, b: float, d, vd, ad, reason: str, status, **diag_extra) -> Plan:
    """The :class:`Plan` (``status``) that brakes at ``b`` from ``plan``'s first state to a stop
    along the lateral profile ``(d, ḋ, d̈)`` on the plan's grid, built by the one constructor of
    replacing plans (:func:`mmdopt.plans.replacement_plan`)."""
    t = np.asarray(plan.t, dtype=np.float64)
    tp = t - t[0]
    s0, v0 = float(plan.s[0]), max(float(plan.vs[0]), 0.0)
    s = _braking(s0, v0, b, tp)
    vs = np.maximum(v0 - b * tp, 0.0)
    as_ = np.where(vs > 0.0, -b, 0.0)
    arrays = dict(s=s, d=d, vs=vs, vd=vd, as_=as_, ad=ad)
    return replacement_plan(plan, path, arrays, status, reason, shield_decel=b, **diag_extra)


def _lateral_profile(d0: float, vd0: float, centre: float, vs, tp, a_lat: float):
    """``(d, ḋ, d̈)`` on ``tp`` moving from ``(d0, vd0)`` to rest at ``centre`` along the
    quintic of the shortest duration (0.5 … 6 s, every 0.25 s) whose lateral acceleration stays
    within ``a_lat`` and whose lateral speed stays within 0.3 × the speed ``vs`` (a heading
    within 17° of the path: a car moves sideways only as it moves on); ``None`` if none does."""
    for T in np.arange(0.5, 6.0 + 1e-9, 0.25):
        A = np.array(
            [[T**3, T**4, T**5], [3 * T**2, 4 * T**3, 5 * T**4], [6 * T, 12 * T**2, 20 * T**3]]
        )
        rhs = np.array([centre - d0 - vd0 * T, -vd0, 0.0])
        c3, c4, c5 = np.linalg.solve(A, rhs)
        tau = np.minimum(tp, T)
        d = d0 + vd0 * tau + c3 * tau**3 + c4 * tau**4 + c5 * tau**5
        vd = np.where(tp < T, vd0 + 3 * c3 * tau**2 + 4 * c4 * tau**3 + 5 * c5 * tau**4, 0.0)
        ad = np.where(tp < T, 6 * c3 * tau + 12 * c4 * tau**2 + 20 * c5 * tau**3, 0.0)
        if np.max(np.abs(ad)) <= a_lat and np.all(np.abs(vd) <= 0.3 * vs + 1e-9):
            return d, vd, ad
    return None


def lane_braking_plan(
    plan: Plan,
    path: frenet.ReferencePath,
    decel: float,
    centre: float,
    lateral_accel: float,
    *,
    reason: str = "",
    status: PlanStatus = PlanStatus.FALLBACK,
) -> Plan | None:
    """The braking fallback of ``plan`` that finishes the move to the lane centre ``centre``
    (m) while it brakes at ``decel`` (m/s²) to a stop: the lateral offset follows a quintic from
    the plan's first lateral state to rest at ``centre`` within ``lateral_accel`` (m/s²) and a
    heading within 17° of the path; ``None`` when no such move ends before the car is too slow
    to make it.  A :class:`Plan` with status FALLBACK, as :func:`braking_plan`."""
    b = float(decel)
    if not (math.isfinite(b) and b > 0):
        raise ValueError(f"decel must be a finite number > 0, got {decel!r}")
    if not (math.isfinite(float(lateral_accel)) and float(lateral_accel) > 0):
        raise ValueError(f"lateral_accel must be a finite number > 0, got {lateral_accel!r}")
    if not math.isfinite(float(centre)):
        raise ValueError(f"centre must be a finite lateral offset, got {centre!r}")
    t = np.asarray(plan.t, dtype=np.float64)
    tp = t - t[0]
    v0 = max(float(plan.vs[0]), 0.0)
    vs = np.maximum(v0 - b * tp, 0.0)
    lat = _lateral_profile(
        float(plan.d[0]), float(plan.vd[0]), float(centre), vs, tp, float(lateral_accel)
    )
    if lat is None:
        return None
    d, vd, ad = lat
    return _fallback(plan, path, b, d, vd, ad, reason, status, shield_lane_centre=float(centre))


def _why(rule: str, chk: PlanCheck, plan: Plan, obstacles, lat, cross, c: RSSConfig) -> str:
    """The reason :func:`shield` gives when ``plan`` fails ``rule`` with ``chk``."""
    if rule == "longitudinal":
        ob = np.asarray(obstacles, dtype=np.float64).reshape(-1, 3)[chk.obstacle]
        return (
            f"the plan closes to {chk.margin + c.contact + c.margin:.2f} m (needs "
            f"{c.contact + c.margin:.2f} m) at t = {chk.time:.2f} s on obstacle {chk.obstacle}, "
            f"{ob[0] - plan.s[0]:.1f} m ahead at {ob[2]:.1f} m/s, in the RSS longitudinal "
            "worst case"
        )
    if rule == "lateral":
        ob = lat[chk.obstacle]
        return (
            f"the plan's side gap to obstacle {chk.obstacle} ({ob[1] - plan.d[0]:+.1f} m "
            f"lateral, {ob[0] - plan.s[0]:+.1f} m along, at {ob[3]:+.2f} m/s sideways) falls "
            f"{-chk.margin:.2f} m short of the RSS lateral safe distance at t = {chk.time:.2f} s"
        )
    cr = cross[chk.obstacle]
    return (
        f"crossing {chk.obstacle}: a car may reach the conflict area at "
        f"{cr[0] - plan.s[0]:.1f} m ahead by t = {chk.time:.2f} s, and braking at b_min "
        f"after the plan stops {-chk.margin:.2f} m too late to stay "
        f"{c.margin:.2f} m short of it"
    )


def _lane_targets(plan: Plan, centres: np.ndarray, c: RSSConfig) -> list[float]:
    """The lane centres a fallback may finish a move to (:func:`lane_braking_plan`): only a
    move under way (the ego off every lane centre or moving sideways), into one of the two
    lanes either side of it, the one the plan was heading to first; none without
    ``lateral_accel`` or centres."""
    dd0, vd0 = float(plan.d[0]), float(plan.vd[0])
    if not (c.lateral_accel > 0 and centres.size):
        return []
    if np.min(np.abs(centres - dd0)) <= 0.1 and abs(vd0) <= 0.1:
        return []
    below, above = centres[centres <= dd0], centres[centres >= dd0]
    side = [float(below.max())] if below.size else []
    side += [float(above.min())] if above.size else []
    return sorted(set(side), key=lambda cen: abs(cen - float(plan.d[-1])))


def _shield_inputs(plan, config, lane_centres, crossings, lateral_states, replace):
    """:func:`shield`'s inputs checked (a ValueError naming the bad one): ``(config, lane
    centres, crossings or None, lateral states or None)``; the lateral states are dropped
    without ``RSSConfig.lateral``, the only setting under which the lateral rule is checked."""
    c = RSSConfig() if config is None else config
    if not isinstance(c, RSSConfig):
        raise ValueError(f"config must be an RSSConfig, got {type(c).__name__}")
    if not isinstance(plan, Plan):
        raise ValueError(f"plan must be an mmdopt.Plan, got {type(plan).__name__}")
    try:
        centres = np.asarray(tuple(lane_centres), dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        centres = np.array([np.nan])
    if not np.all(np.isfinite(centres)):
        raise ValueError(f"lane_centres must be finite lateral offsets (m), got {lane_centres!r}")
    if not isinstance(replace, str):
        raise ValueError(f"replace must be a reason (str), got {type(replace).__name__}")
    cross = None if crossings is None else _crossings(crossings)
    lat = None if lateral_states is None else _lateral_states(lateral_states, "lateral_states")
    return c, centres, cross, (lat if c.lateral else None)


def shield(
    plan: Plan,
    path: frenet.ReferencePath,
    obstacles: np.ndarray,
    config: RSSConfig | None = None,
    *,
    executed: float,
    lane_centres=(),
    crossings=None,
    lateral_states=None,
    replace: str = "",
) -> tuple[Plan, ShieldRecord]:
    """Check ``plan`` with :func:`check_plan` (``executed`` seconds of it run before the next
    check) against ``obstacles`` ``(O, 3)`` = current ``(s, d, ṡ)`` in ``path``'s frame; return
    it unchanged when it passes, else the gentlest checked braking fallback (the plan's lateral
    path braking at ``b_gentle`` … below ``b_min``, checked as a plan is; then
    :func:`braking_plan` at ``b_min``, harder up to ``b_emergency``; the hardest when none
    passes), with a :class:`ShieldRecord` of what was done and why.  With
    ``config.lateral_accel > 0`` and ``lane_centres`` (m), at each level a fallback that finishes
    the move to a lane centre (:func:`_lane_targets`, :func:`lane_braking_plan`) is tried first,
    so a plan replaced mid-lane-change does not leave the ego between two lanes.

    Two more rules apply when their inputs are given: ``crossings`` ``(C, 3)`` =
    ``(s_in, s_out, t_arrive)`` in ``path``'s frame, the conflict areas of crossing routes
    (:func:`check_crossings`), and, with ``config.lateral``, ``lateral_states`` ``(O', 4)`` =
    current ``(s, d, ṡ, ḋ)`` of the cars around (:func:`obstacle_states_from_cartesian` with
    ``lateral=True``; RSS's lateral distance to the cars beside, :func:`check_lateral`).  The
    plan passes when every rule that applies passes, in the order longitudinal, lateral,
    crossing; the first it fails is :attr:`ShieldRecord.rule` and names itself in the reason.
    Each fallback must then pass the same rules along its own profile (``executed`` seconds of
    it for the gentle levels, its whole horizon from ``b_min`` on; a fallback that holds the
    offset has ``ḋ = 0``).  Without ``crossings`` and ``lateral_states`` the shield is the
    longitudinal one alone.  ``replace`` (a reason): replace the plan even when it passes, by the
    checked braking fallbacks from ``b_min`` on (rule ``"unsafe"``: the receding loop passes the
    planner's own report that the plan meets every future of some car)."""
    c, centres, cross, lat = _shield_inputs(
        plan, config, lane_centres, crossings, lateral_states, replace
    )

    def rules(t, s, d, vs, vd, ex: float) -> list[tuple[str, PlanCheck]]:
        """The rules that apply, checked on one profile, in the order they are reported."""
        out = [("longitudinal", check_plan(t, s, d, vs, obstacles, c, executed=ex))]
        if lat is not None:
            out.append(("lateral", check_lateral(t, s, d, vd, lat, c, executed=ex)))
        if cross is not None:
            out.append(("crossing", check_crossings(t, s, vs, cross, c, executed=ex)))
        return out

    def passes(t, s, d, vs, vd, ex: float) -> bool:
        return all(chk.safe for _, chk in rules(t, s, d, vs, vd, ex))

    checks = rules(plan.t, plan.s, plan.d, plan.vs, plan.vd, executed)
    failed = [(name, chk) for name, chk in checks if not chk.safe]
    if not failed and not replace:
        least = min(chk.margin for _, chk in checks)
        return plan, ShieldRecord(False, "", least, 0.0, True, checks[0][1].n_checked)
    if failed:
        rule, chk = failed[0]
        why = _why(rule, chk, plan, obstacles, lat, cross, c)
    else:  # the plan passes the rules, but its planner says it meets every future of a car
        rule, chk, why = "unsafe", PlanCheck(False, math.nan, -1, 0.0, 0), replace

    def record(decel: float, safe: bool) -> ShieldRecord:
        return ShieldRecord(True, why, chk.margin, decel, safe, chk.n_checked, rule)

    decels = np.unique(np.linspace(c.b_min, c.b_emergency, 5))
    tp = np.asarray(plan.t, dtype=np.float64) - float(plan.t[0])
    horizon = float(tp[-1])
    s0, v0 = float(plan.s[0]), max(float(plan.vs[0]), 0.0)
    d0 = np.full_like(tp, float(plan.d[0]))
    vd_hold = np.zeros_like(tp)
    targets = _lane_targets(plan, centres, c)
    # below b_min: the plan's lateral profile, braking gently, checked as a plan is (its first
    # ``executed`` seconds, then b_min): the gentlest that passes keeps the same guarantee
    gentle = []
    if c.b_gentle < c.b_min and rule != "unsafe":
        gentle = np.linspace(c.b_gentle, c.b_min, GENTLE_LEVELS + 1)[:-1]
    d_plan = np.asarray(plan.d, np.float64)
    vd_plan = np.asarray(plan.vd, np.float64)
    for b_try in gentle:  # the profiles checked before one plan is built
        vs = np.maximum(v0 - b_try * tp, 0.0)
        prof = _braking(s0, v0, float(b_try), tp)
        if passes(tp, prof, d_plan, vs, vd_plan, executed):
            reason = f"{why}; braking at {b_try:.3g} m/s² along the plan's lateral path"
            fb = _fallback(
                plan, path, float(b_try), d_plan, vd_plan,
                np.asarray(plan.ad, np.float64), reason, PlanStatus.SHIELDED,
            )  # fmt: skip
            return fb, record(float(b_try), True)
    for b_try in decels:  # each fallback checked along its own profile (executed: all of it)
        for cen in targets:
            fb = lane_braking_plan(
                plan,
                path,
                float(b_try),
                cen,
                c.lateral_accel,
                reason=f"{why}; braking at {b_try:g} m/s² into the lane at {cen:g} m",
                status=PlanStatus.SHIELDED,
            )
            if fb is not None and passes(fb.t, fb.s, fb.d, fb.vs, fb.vd, horizon):
                return fb, record(float(b_try), True)
        vs = np.maximum(v0 - b_try * tp, 0.0)
        prof = _braking(s0, v0, float(b_try), tp)
        if passes(tp, prof, d0, vs, vd_hold, horizon):
            reason = f"{why}; braking at {b_try:g} m/s²"
            fb = braking_plan(plan, path, float(b_try), reason=reason, status=PlanStatus.SHIELDED)
            return fb, record(float(b_try), True)
    b = float(decels[-1])
    fb = braking_plan(
        plan, path, b, reason=f"{why}; braking at {b:g} m/s²", status=PlanStatus.SHIELDED
    )
    fb = dataclasses.replace(fb, message=fb.message + " (no braking passes the check)")
    return fb, record(b, False)
