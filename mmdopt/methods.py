"""The registry of planning methods: one record per method, read by every part of the toolkit.

Every method runs the *same* optimiser (:mod:`mmdopt.algorithm`); a method is what differs
around it (paper, "Baselines": "we just replace our MMD cost with a deterministic collision
cost"): which obstacle samples enter the cost (a reduced-set selector of
:mod:`mmdopt.reduced_set`, or all of them), which collision term scores them
(:data:`mmdopt.collision.COLLISION_TERMS`), its default risk level ε and the rule that maps ε to
its settings (:func:`mmdopt.risk.config_for_risk`), the optional risk passes it runs around
Algorithm 1 (:mod:`mmdopt.schedule`), and its label and colour in tables and figures.

==================  ==========================================  ===============================
method              obstacle samples in the cost                collision term
==================  ==========================================  ===============================
``"mmd"``           m-sample reduced set by MMD, weights ᾱ      ``embedding``: ``w_mmd · l_dist``
``"random"``        m-sample uniformly random subset, ᾱ         ``embedding``
``"degroot"``       m-sample de Groot set (deepest conflict     ``scenario``: ``w_coll · Σ f̄``
                    with a constant-velocity ego guess)         (deterministic scenario cost)
``"scenario_all"``  all n samples                               ``scenario``
``"saa"``           all n samples                               ``chance``: SAA's
                                                                ``w_saa · Σ_o (π̂_o − ε)₊/ε``
``"cvar"``          all n samples                               ``tail``: the journal version's
                                                                ``w_cvar · Σ_o CVaR_α(g_o)``,
                                                                α = 1 − ε
==================  ==========================================  ===============================

``cvar`` is the journal version's third cost (MMD-OPT, ``compute_cvar_obs``): the CVaR at level
α of each sample's largest ellipse violation.  Its α is tied to the risk dial by α = 1 − ε: the
CVaR then averages the worst ε-fraction of the futures, the same tail the chance constraint
P(collision) ≤ ε speaks of (the journal fixes α = 0.98, which is the "linear" margin mode's
value here).  As SAA in this toolkit, it plans on every sample (the journal gives CVaR and SAA
as many samples as MMD-Opt's reduced set; here they may use them all, which only helps them).

**A new method is one record** (:class:`PlanMethod`) passed to :func:`register`; nothing else
in the package, the benchmarks or the CLI needs a change::

    import mmdopt
    mmdopt.methods.register(mmdopt.methods.PlanMethod(
        name="scenario_random", label="scenario, random set", selector="uniform",
        collision="scenario"))
    mmdopt.plan(ego, road, obstacles, method="scenario_random")

**Scenario formulation chosen** (the authors' reference code puts the reduced-set collision
constraints into its non-convex polar-form projection instead): collisions enter as a
*deterministic collision cost* on the scenario samples, as the paper's Baselines paragraph says.
Linearised half-planes as projection rows were not chosen: the normal of each half-plane depends
on the sample's own trajectory, so the constraint matrix would differ per sample and the batched
projection (one factorisation shared by the batch) would no longer apply.

This is the only module of the package that compares plan-method names (checked by
``tests/test_architecture.py``); everything else reads a record's fields.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from .collision import COLLISION_TERMS
from .config import MMD_RISK_HITS, W_COVER, MMDOptConfig
from .reduced_set import SELECTORS

__all__ = [
    "PlanMethod",
    "OPTIONAL_PASSES",
    "BUILTIN",
    "PLAN_METHODS",
    "register",
    "unregister",
    "get",
    "names",
    "records",
]

#: the optional risk passes a method may run around Algorithm 1 in the "samples" margin mode
#: (:mod:`mmdopt.schedule`): the re-selection pass, the nearest-futures pass, the margin ladder
#: and the final check's tail passes
OPTIONAL_PASSES = ("reselect", "nearest", "ladder", "tail")


def _no_settings(eps: float) -> Mapping[str, Any]:
    return {}


@dataclass(frozen=True)
class PlanMethod:
    """One planning method: everything the toolkit needs to know of it.

    name : the name ``plan(..., method=name)`` takes (and the CSVs' ``method`` column)
    label, colour : how tables and figures name and draw it (a matplotlib colour)
    selector : the reduced-set selector of :data:`mmdopt.reduced_set.SELECTORS` whose m samples
        the cost plans against, or ``None``: all n samples (the margins then use k-NN clusters)
    collision : the collision term, one of :data:`mmdopt.collision.COLLISION_TERMS`
    default_risk : ε when ``risk`` is not given (:func:`mmdopt.risk.config_for_risk`)
    risk_settings : the rule ε → the config fields it sets besides the margin mode and ε
        itself (field names of :meth:`mmdopt.MMDOptConfig.replace`)
    passes : the optional risk passes it runs (:data:`OPTIONAL_PASSES`; each also needs its
        config switch: ``reselect`` > 0, ``nearest_futures`` > 0, a ``margin_ladder``,
        ``tail_passes`` > 0); "reselect" and "tail" need a selector
    auto_reselect : with ``safety.reselect = None`` (automatic) in the "samples" margin mode, the
        re-selection pass adds m/2 samples (else 0)
    auto_risk_hits : with ``safety.risk_hits = None`` (automatic) in the "samples" margin mode,
        the planning futures a plan drawn from a predictor may meet with its bound ≤ ε, which
        sets how many futures it draws (:func:`mmdopt.risk.samples_for_risk`)
    selection_pool : in the "samples" mode, with more samples than ``schedule.selection_pool``,
        the selector sees a random pool of that size (a kernel selector's n² Gram would
        dominate); the margins and the final check still use every sample
    ego_guess : the selector scores samples against a constant-velocity ego guess (de Groot)
    lateral_features : the selector's features have their lateral offsets scaled by
        ``selection.rs_lateral_scale`` (an anisotropic kernel; not for a selector that scores
        conflicts in metres)
    max_futures : the most futures per obstacle the benchmarks let it draw from a predictor
        (beyond it a plan reports ``risk floor``); the package's own cap is the
        :class:`~mmdopt.predict.Forecast`'s ``max_samples``
    """

    name: str
    label: str
    selector: str | None
    collision: str
    default_risk: float = 0.005
    risk_settings: Callable[[float], Mapping[str, Any]] = field(default=_no_settings)
    passes: tuple[str, ...] = ()
    auto_reselect: bool = False
    auto_risk_hits: int = 0
    selection_pool: bool = False
    ego_guess: bool = False
    lateral_features: bool = True
    max_futures: int = 5000
    colour: str = "tab:olive"

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name or "," in self.name:
            raise ValueError(f"PlanMethod.name must be a non-empty string without ',', got "
                             f"{self.name!r}")  # fmt: skip
        if not isinstance(self.label, str):
            raise ValueError(f"PlanMethod.label must be a string, got {self.label!r}")
        if self.selector is not None and self.selector not in SELECTORS:
            raise ValueError(
                f"PlanMethod.selector must be None or one of {SELECTORS}, got {self.selector!r}"
            )
        if self.collision not in COLLISION_TERMS:
            raise ValueError(
                f"PlanMethod.collision must be one of {COLLISION_TERMS}, got {self.collision!r}"
            )
        r = self.default_risk
        if isinstance(r, bool) or not isinstance(r, int | float) or not 0 < r < 0.5:
            raise ValueError(f"PlanMethod.default_risk must be in (0, 0.5), got {r!r}")
        if not callable(self.risk_settings):
            raise ValueError("PlanMethod.risk_settings must be callable: eps -> {field: value}")
        passes = tuple(self.passes)
        bad = [p for p in passes if p not in OPTIONAL_PASSES]
        if bad:
            raise ValueError(f"PlanMethod.passes must be among {OPTIONAL_PASSES}, got {bad}")
        if self.selector is None and {"reselect", "tail", "nearest", "ladder"} & set(passes):
            raise ValueError(
                "PlanMethod.passes: the re-selection, nearest, ladder and tail passes add "
                "samples to a reduced set, so they need a selector"
            )
        object.__setattr__(self, "passes", passes)
        for name in ("auto_risk_hits", "max_futures"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < (0 if "hits" in name else 1):
                raise ValueError(f"PlanMethod.{name} must be an int >= 0 (>= 1 for max_futures), "
                                 f"got {v!r}")  # fmt: skip

    # -------------------------------------------------------------------------- derived
    @property
    def all_samples(self) -> bool:
        """Whether it plans on every sample (no selector; its margins use k-NN clusters)."""
        return self.selector is None

    def runs(self, name: str) -> bool:
        """Whether the optional pass ``name`` (:data:`OPTIONAL_PASSES`) is one of its own."""
        return name in self.passes

    def settings_for_risk(self, eps: float) -> dict[str, Any]:
        """The config fields ε sets for this method (:func:`mmdopt.risk.config_for_risk`)."""
        kw: dict[str, Any] = dict(margin_mode="samples", risk=eps)
        kw.update(self.risk_settings(eps))
        return kw

    def reselect(self, config: MMDOptConfig) -> int:
        """The re-selection pass size it runs with: ``safety.reselect``, or when that is
        ``None`` (automatic) ``max(1, m // 2)`` for a method with ``auto_reselect`` in the
        "samples" margin mode, else 0."""
        if config.safety.reselect is not None:
            return int(config.safety.reselect)
        if self.auto_reselect and config.safety.margins.margin_mode == "samples":
            return max(1, config.selection.reduced_set_size // 2)
        return 0

    def risk_hits(self, config: MMDOptConfig) -> int:
        """The planning futures a plan may meet with its 95 % bound ≤ ε (which sets how many it
        draws from a predictor): ``safety.risk_hits``, or when that is ``None`` (automatic)
        :attr:`auto_risk_hits` in the "samples" margin mode, else 0."""
        if config.safety.risk_hits is not None:
            return int(config.safety.risk_hits)
        if config.safety.margins.margin_mode == "samples":
            return int(self.auto_risk_hits)
        return 0


# ------------------------------------------------------------------------------ the built-ins
def _mmd_settings(eps: float) -> Mapping[str, Any]:
    # the coverage term on the inflated ellipses (the caller's re-selection size is kept)
    return {"w_cover": W_COVER}


def _random_settings(eps: float) -> Mapping[str, Any]:
    return {"w_cover": W_COVER}


def _saa_settings(eps: float) -> Mapping[str, Any]:
    return {"saa_eps": None}  # the chance level follows ε (MMDOptConfig.saa_level)


def _cvar_settings(eps: float) -> Mapping[str, Any]:
    return {"cvar_alpha": None}  # α = 1 − ε (MMDOptConfig.cvar_level)


#: the built-in methods, in the order of the public API (the first is MMD-Opt)
BUILTIN: tuple[PlanMethod, ...] = (
    PlanMethod(
        name="mmd",
        label="MMD-Opt",
        selector="kernel-cem",
        collision="embedding",
        risk_settings=_mmd_settings,
        passes=("reselect", "nearest", "ladder", "tail"),
        auto_risk_hits=MMD_RISK_HITS,
        selection_pool=True,
        max_futures=50_000,
        colour="tab:blue",
    ),
    PlanMethod(
        name="degroot",
        label="de Groot (scenario)",
        selector="conflict",
        collision="scenario",
        passes=("reselect", "tail"),
        ego_guess=True,
        lateral_features=False,
        colour="goldenrod",
    ),
    PlanMethod(
        name="random",
        label="random reduced set",
        selector="uniform",
        collision="embedding",
        risk_settings=_random_settings,
        passes=("reselect", "tail"),
        colour="tab:gray",
    ),
    PlanMethod(
        name="saa",
        label="SAA",
        selector=None,
        collision="chance",
        risk_settings=_saa_settings,
        colour="tab:green",
    ),
    PlanMethod(
        name="cvar",
        label="CVaR",
        selector=None,
        collision="tail",
        risk_settings=_cvar_settings,
        colour="tab:brown",
    ),
    PlanMethod(
        name="scenario_all",
        label="scenario, all samples",
        selector=None,
        collision="scenario",
        colour="tab:purple",
    ),
)
#: the names of the built-in methods (:func:`names` also lists registered ones)
PLAN_METHODS: tuple[str, ...] = tuple(m.name for m in BUILTIN)


class _Registry:
    """The registered methods by name, in registration order (the built-ins first)."""

    def __init__(self, methods: tuple[PlanMethod, ...]) -> None:
        self._methods: dict[str, PlanMethod] = {m.name: m for m in methods}

    def register(self, method: PlanMethod, replace: bool) -> PlanMethod:
        if not isinstance(method, PlanMethod):
            raise ValueError(f"method must be a PlanMethod, got {type(method).__name__}")
        if method.name in self._methods and not replace:
            raise ValueError(
                f"a method named {method.name!r} is already registered (replace=True replaces it)"
            )
        self._methods[method.name] = method
        return method

    def unregister(self, name: str) -> None:
        if name in PLAN_METHODS:
            raise ValueError(f"{name!r} is a built-in method and cannot be unregistered")
        if name not in self._methods:
            raise ValueError(f"no method named {name!r} is registered")
        del self._methods[name]

    def get(self, name: Any, argument: str) -> PlanMethod:
        if isinstance(name, PlanMethod):
            return name
        hit = self._methods.get(name) if isinstance(name, str) else None
        if hit is None:
            raise ValueError(f"{argument} must be one of {tuple(self._methods)}, got {name!r}")
        return hit

    def names(self) -> tuple[str, ...]:
        return tuple(self._methods)


#: the one registry (with the planner cache, the method's only mutable module state)
REGISTRY = _Registry(BUILTIN)


def register(method: PlanMethod, *, replace: bool = False) -> PlanMethod:
    """Add ``method`` to the registry (``replace=True`` replaces one of the same name); returns
    it.  From then on ``plan``, the receding loop, the benchmarks and the CLI accept its name."""
    return REGISTRY.register(method, replace)


def unregister(name: str) -> None:
    """Remove a registered (not built-in) method."""
    REGISTRY.unregister(name)


def get(name: str | PlanMethod, argument: str = "method") -> PlanMethod:
    """The record of the method ``name`` (a record passes through); ``ValueError`` naming
    ``argument`` and listing the registered names otherwise."""
    return REGISTRY.get(name, argument)


def names() -> tuple[str, ...]:
    """The registered method names, the built-ins first."""
    return REGISTRY.names()


def records() -> tuple[PlanMethod, ...]:
    """The registered records, in :func:`names` order."""
    return tuple(REGISTRY.get(n, "method") for n in REGISTRY.names())
