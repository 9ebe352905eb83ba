"""Argument types shared by the ``mmdopt`` sub-commands (argparse ``type=`` callables).

Each raises ``argparse.ArgumentTypeError``, which argparse turns into exit status 2 with a message
naming the option.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from pathlib import Path

from .executors import ADDRESS_FORMS, EXECUTORS, parse_ray_address


def method_list(
    allowed: Sequence[str] | Callable[[], Sequence[str]],
) -> Callable[[str], list[str]]:
    """``"a,b"`` -> ``["a", "b"]`` (duplicates dropped), every name one of ``allowed`` (or of
    ``allowed()`` at parse time: :func:`mmdopt.methods.names`, so a method registered before the
    command line is parsed is a choice)."""

    def parse(s: str) -> list[str]:
        names = tuple(allowed() if callable(allowed) else allowed)
        ms = [m.strip() for m in s.split(",") if m.strip()]
        if not ms:
            raise argparse.ArgumentTypeError("needs at least one method")
        bad = [m for m in ms if m not in names]
        if bad:
            raise argparse.ArgumentTypeError(
                f"unknown method(s) {', '.join(bad)}; choose from {', '.join(names)}"
            )
        return list(dict.fromkeys(ms))

    return parse


def positive_int(s: str) -> int:
    try:
        v = int(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {s!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def nonneg_int(s: str) -> int:
    try:
        v = int(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {s!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {v}")
    return v


def positive_float(s: str) -> float:
    try:
        v = float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {s!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {s!r}")
    return v


def int_list(s: str) -> list[int]:
    """``"1,5,10"`` -> ``[1, 5, 10]``, every entry a positive integer."""
    try:
        v = [int(x) for x in s.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {s!r}") from None
    if not v or min(v) < 1:
        raise argparse.ArgumentTypeError(f"expected positive integers, got {s!r}")
    return v


def existing_file(s: str) -> Path:
    p = Path(s)
    if not p.is_file():
        raise argparse.ArgumentTypeError(f"file {s!r} does not exist")
    return p


def existing_path(s: str) -> Path:
    """A file or a folder that exists."""
    p = Path(s)
    if not p.exists():
        raise argparse.ArgumentTypeError(f"{s!r} does not exist")
    return p


def ray_address(s: str) -> str:
    """``--address``: a Ray cluster's address in one of the forms of
    :func:`~mmdopt.bench.executors.parse_ray_address` (``auto``, ``ray://HOST:PORT``,
    ``HOST:PORT``), refused at once otherwise (Ray would retry a malformed one for half a
    minute).  Whether a cluster answers there is checked before the command starts."""
    try:
        parse_ray_address(s)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return s


def add_executor(q: argparse.ArgumentParser) -> None:
    """``--executor local|ray`` and ``--address`` (every runner that uses executors.run_tasks)."""
    q.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="local",
        help="local process pool (default) or ray (pip install 'mmdopt[ray]')",
    )
    q.add_argument(
        "--address",
        type=ray_address,
        default=None,
        help=f"with --executor ray: address of an existing Ray cluster, {ADDRESS_FORMS} "
        "(default: a local one)",
    )
