"""Predictor protocol and predictors: black-box samplers of obstacles' futures.

``predictor.sample(history (O, H, 2), context, n, key) -> (O, n, K, 2)`` Cartesian samples on
the planner's grid (:mod:`mmdopt.predict.base`), ready for :func:`mmdopt.plan`.  Three
predictors: :class:`ConstantVelocity`, :class:`LaneAware` (keep / left / right) and
:class:`Learned` (a mixture-density network in JAX, shipped weights); :func:`make_predictor`
builds one by name ("cv", "lane", "learned").
"""

from __future__ import annotations

from .base import (
    GAP_NONE,
    Forecast,
    PredictionContext,
    Predictor,
    cartesian_to_lane,
    lane_to_cartesian,
)
from .baselines import ConstantVelocity, LaneAware
from .metrics import evaluate_predictor, kde_nll, min_ade_fde
from .resample import resample_prediction

__all__ = [
    "GAP_NONE",
    "Forecast",
    "PREDICTORS",
    "PredictionContext",
    "Predictor",
    "ConstantVelocity",
    "LaneAware",
    "Learned",
    "cartesian_to_lane",
    "lane_to_cartesian",
    "make_predictor",
    "evaluate_predictor",
    "kde_nll",
    "min_ade_fde",
    "resample_prediction",
]

#: Predictor names accepted by :func:`make_predictor` (and ``--predictor``).
PREDICTORS = ("learned", "lane", "cv")


def make_predictor(name: str, **kw) -> Predictor:
    """``"cv"`` → :class:`ConstantVelocity`, ``"lane"`` → :class:`LaneAware`,
    ``"learned"`` → :class:`Learned` (shipped weights unless ``weights=PATH``)."""
    if name == "cv":
        return ConstantVelocity(**kw)
    if name == "lane":
        return LaneAware(**kw)
    if name == "learned":
        from .learned import Learned

        return Learned(**kw)
    raise ValueError(f"predictor must be one of {PREDICTORS}, got {name!r}")


def __getattr__(name):  # equinox/optax are imported only when the learned model is used
    if name == "Learned":
        from .learned import Learned

        return Learned
    raise AttributeError(name)
