"""Checks of the command line's inputs that are not one option's value alone: the output paths
and the executor's address.

Each check raises ``ValueError`` with the reason (never the option's name: the caller knows the
option and reports ``error: argument --OPTION: <reason>``, exit status 2), and each runs before
anything is written, so a refused command leaves nothing behind.  The scenario files of
``bench ngsim`` / ``predictor`` are checked by :mod:`mmdopt.bench.ngsim.inputs`.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import tempfile
from pathlib import Path

__all__ = ["check_out_folder", "check_out_file", "check_address"]


def read_json(path: str | os.PathLike):
    """The parsed JSON value of the file ``path``; ``ValueError`` naming the file when it cannot
    be read or is not valid JSON."""
    import json

    try:
        return json.loads(Path(path).read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path} is not valid JSON: {e}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{path} cannot be read: {e}") from None


def _existing_ancestor(p: Path) -> Path:
    """``p`` or its nearest ancestor that exists."""
    a = p
    while not a.exists() and a.parent != a:
        a = a.parent
    return a


def _probe(folder: Path) -> None:
    """Create and remove an empty folder in ``folder``: whether new entries can be written there.
    (``os.access`` says yes to root everywhere, also in ``/proc`` or on a read-only mount.)"""
    try:
        d = tempfile.mkdtemp(prefix=".mmdopt-write-check-", dir=folder)
    except OSError as e:
        raise ValueError(f"{str(folder)!r} does not accept new files ({e.strerror})") from None
    with contextlib.suppress(OSError):
        os.rmdir(d)


def check_out_folder(out: str | os.PathLike) -> None:
    """``out`` is a folder this process can write into, or a path where one can be created
    (every missing parent included).  Nothing is left behind; raises ``ValueError``."""
    p = Path(out)
    if p.exists() and not p.is_dir():
        raise ValueError(f"{str(out)!r} exists and is not a folder")
    a = _existing_ancestor(p)
    if not a.is_dir():
        raise ValueError(f"cannot create folder {str(out)!r}: {str(a)!r} is a file")
    try:
        _probe(a)
    except ValueError as e:
        what = "cannot be written" if a == p else "cannot be created"
        raise ValueError(f"folder {str(out)!r} {what}: {e}") from None


def check_out_file(path: str | os.PathLike) -> None:
    """``path`` is a file that can be (over)written: not a folder, and its folder exists and is
    writable or can be created.  Nothing is left behind; raises ``ValueError``."""
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{str(path)!r} is a folder, not a file")
    if p.exists() and not os.access(p, os.W_OK):
        raise ValueError(f"file {str(path)!r} is not writable (permission denied)")
    try:
        check_out_folder(p.parent)
    except ValueError as e:
        raise ValueError(f"cannot write {str(path)!r}: {e}") from None


def check_address(executor: str, address: str | None) -> None:
    """``--address`` is the address of a Ray cluster: only meaningful with ``--executor ray``;
    a ``ray://`` address needs Ray's client (grpcio, ``pip install 'ray[client]'``)."""
    if address is None:
        return
    if executor != "ray":
        raise ValueError(
            f"{address!r} is the address of a Ray cluster: it needs --executor ray "
            f"(got --executor {executor})"
        )
    if not address.strip():
        raise ValueError("is empty (omit it to start a local Ray instance)")
    if address.startswith("ray://") and importlib.util.find_spec("grpc") is None:
        raise ValueError(
            "a ray:// address needs Ray's client, which is not installed: "
            "pip install 'ray[client]' (or 'mmdopt[ray]')"
        )
