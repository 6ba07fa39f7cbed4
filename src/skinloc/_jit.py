"""The one way skinloc compiles a kernel: ``numba.njit`` with on-disk caching."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba

__all__ = ["all_finite", "compiled_entry", "jit", "prange"]

prange = numba.prange


def jit(**kw: Any):
    """``numba.njit(cache=True, fastmath=True, nogil=True, **kw)`` (``kw`` may override them)."""
    return numba.njit(**{"cache": True, "fastmath": True, "nogil": True, **kw})


@numba.njit(cache=True, nogil=True)  # not fastmath: it would assume NaN and inf away
def all_finite(x: Any) -> bool:  # pragma: no cover - compiled
    """Whether every value of the 1-D array ``x`` is finite (about 0.15 µs for 64 values).

    The compiled kernels are built with ``fastmath``, which assumes no NaN or infinity: one
    such value in a frame can make them index out of bounds. Frames are checked here first.
    """
    for i in range(x.shape[0]):
        v = x[i]
        if not v - v == 0:
            return False
    return True


def compiled_entry(kernel: Any, *args: Any) -> Callable[..., Any]:
    """The compiled code of ``kernel`` for the types of ``args``, callable without dispatch.

    Numba types every argument of every call to choose the compiled version; a named tuple of
    arrays is typed field by field in Python (about 2 us for a search's tables), a plain array
    in C. A caller that passes the same tables on every call, and arrays of the same types,
    may call this instead (compiled, or loaded from the cache, now). Arguments of other types
    must never reach it: it does not check them.
    """
    kernel(*args)
    sig = tuple(numba.typeof(a) for a in args)
    return kernel.overloads[sig].entry_point
