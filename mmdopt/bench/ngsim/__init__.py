"""Real traffic: recorded NGSIM US-101 scenes (CommonRoad) as a planning benchmark.

:mod:`.scene` reads a CommonRoad file (the only module importing ``commonroad``) into arrays and
builds lane chains, reference paths and predictor inputs; :mod:`.data` the train/held-out split
and training windows; :mod:`.metric` footprints and the at-fault rule; :mod:`.runner` the
benchmark (:func:`run_ngsim`); :mod:`.crcheck` CommonRoad's checkers on each plan;
:mod:`.reactive` CommonRoad's reactive planner as a peer; :mod:`.plot` figures; :mod:`.cli`
the ``bench ngsim`` and ``predictor train|eval`` commands.  See docs/experiments/ngsim.md.
"""

from .runner import RESULT_COLUMNS, NgsimParams, ngsim_config, run_ngsim, select_tasks

__all__ = ["RESULT_COLUMNS", "NgsimParams", "ngsim_config", "run_ngsim", "select_tasks"]
