"""Experiments on the method: scene sources, the metric, runners, executors, plots and the CLI.

The method (:mod:`mmdopt`) never imports this package.
"""

from .results import load_results

__all__ = ["load_results"]
