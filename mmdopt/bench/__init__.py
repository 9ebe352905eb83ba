"""Experiments on the method: scene sources, the metric, runners, executors, plots and the CLI.

The method (:mod:`mmdopt`) never imports this package.  Its names are imported on first use
(PEP 562), so the CLI's ``--help`` imports nothing heavy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .results import load_results

__all__ = ["load_results"]


def __getattr__(name: str) -> Any:
    if name == "load_results":
        from .results import load_results

        return load_results
    raise AttributeError(f"module 'mmdopt.bench' has no attribute {name!r}")
