"""Optional dependencies of the experiments: matplotlib and tqdm (the ``demo`` extra), pandas.

The method (``import mmdopt``, :func:`mmdopt.plan`) needs none of them; the experiments import them
only where they are used, through :func:`require`, whose error names the extra to install.  The
CLI checks a command's needs before it starts (:func:`missing_for`) and exits with status 2.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Iterable
from types import ModuleType
from typing import Any

__all__ = ["EXTRAS", "MissingExtra", "install_hint", "require", "missing_for", "progress_bar"]

#: the pip extra that installs each optional module
EXTRAS = {"matplotlib": "demo", "tqdm": "demo", "pandas": "pandas"}


class MissingExtra(ImportError):
    """An optional dependency is not installed; the message names the extra that installs it."""


def install_hint(module: str) -> str:
    """``pip install -e ".[EXTRA]"`` for ``module``'s extra."""
    top = module.split(".")[0]
    if top not in EXTRAS:
        raise ValueError(f"module must be one of {sorted(EXTRAS)}, got {module!r}")
    return f'pip install -e ".[{EXTRAS[top]}]"'


def require(module: str, purpose: str) -> ModuleType:
    """Import ``module`` (e.g. ``"matplotlib.pyplot"``) or raise :class:`MissingExtra` saying that
    ``purpose`` needs it and how to install it."""
    top = module.split(".")[0]
    hint = install_hint(top)
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtra(f"{purpose} needs {top}, which is not installed: {hint}") from None


def _importable(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def missing_for(modules: Iterable[str]) -> list[str]:
    """The names among ``modules`` that cannot be imported, in order."""
    return [m for m in modules if not _importable(m)]


class _NoBar:
    """A progress bar that shows nothing (``progress=False`` needs no tqdm)."""

    disable = True

    def __init__(self, iterable: Iterable[Any] | None = None, **_: Any) -> None:
        self._iterable = iterable

    def __iter__(self):
        return iter(self._iterable if self._iterable is not None else ())

    def update(self, n: int = 1) -> None:
        pass

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        pass

    def refresh(self) -> None:
        pass

    def close(self) -> None:
        pass


def progress_bar(iterable: Iterable[Any] | None = None, *, progress: bool = True, **kw: Any):
    """``tqdm.auto.tqdm(iterable, **kw)`` when ``progress``, else a bar that shows nothing (and
    needs no tqdm).  Raises :class:`MissingExtra` when ``progress`` and tqdm is not installed."""
    if not progress:
        return _NoBar(iterable)
    tqdm = require("tqdm.auto", "the progress bar").tqdm
    return tqdm(iterable, **kw)
