"""``skinloc._jit``: the compiled kernels' one decorator and the dispatch-free entry."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest

from skinloc._jit import compiled_entry, jit


class _Tables(NamedTuple):
    a: np.ndarray
    b: np.ndarray


@jit(cache=False)
def _weighted(x: np.ndarray, t: _Tables, out: np.ndarray) -> float:  # pragma: no cover
    s = 0.0
    for i in range(x.shape[0]):
        out[i] = x[i] * t.a[i] + t.b[i]
        s += out[i]
    return s


def test_the_compiled_entry_computes_what_the_kernel_does():
    """Called with arguments of the types it was made for, the entry is the kernel."""
    rng = np.random.default_rng(0)
    t = _Tables(rng.normal(size=16), rng.normal(size=16))
    out1, out2 = np.zeros(16), np.zeros(16)
    entry = compiled_entry(_weighted, np.zeros(16, dtype=np.float32), t, out1)
    for _ in range(3):
        x = rng.normal(size=16).astype(np.float32)
        assert entry(x, t, out1) == pytest.approx(_weighted(x, t, out2), rel=1e-12)
        np.testing.assert_allclose(out1, out2, rtol=1e-12)
    assert len(_weighted.overloads) == 1  # the entry added no other version
