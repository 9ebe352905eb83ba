"""Every error class of :mod:`solvers`, in one module that imports nothing else of the package.

All are subclasses of the built-in type a caller would catch anyway (``ValueError`` for bad input,
``ImportError`` for a missing package), so ``except ValueError`` keeps working.
"""

from __future__ import annotations

__all__ = [
    "BackendUnavailableError",
    "InvalidSettingError",
    "NonConvexError",
    "UnknownBackendError",
]


class BackendUnavailableError(ImportError):
    """The backend exists but its package is not installed (the message names the extra)."""


class UnknownBackendError(ValueError):
    """No backend of that name (the message lists the available ones)."""


class NonConvexError(ValueError):
    """``P`` is not positive semidefinite: the QP is non-convex and is refused, never solved.

    Raised when a :class:`~solvers.QP` or :class:`~solvers.QPBatch` is built (or solved with
    ``check_convex=True``); pass ``check_convex=False`` to skip the check on large problems.
    """


class InvalidSettingError(ValueError):
    """A solver setting that the backend does not know, or a common setting with a bad value.

    The message names the key and lists the valid names; the same type on every backend.
    """
