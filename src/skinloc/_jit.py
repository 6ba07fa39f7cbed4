"""The one way skinloc compiles a kernel: ``numba.njit`` with on-disk caching."""

from __future__ import annotations

from typing import Any

import numba

__all__ = ["jit", "prange"]

prange = numba.prange


def jit(**kw: Any):
    """``numba.njit(cache=True, fastmath=True, nogil=True, **kw)``."""
    return numba.njit(cache=True, fastmath=True, nogil=True, **kw)
