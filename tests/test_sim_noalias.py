"""``njit_noalias``: the flag reaches LLVM, the numbers do not change, and the fallback is plain numba."""

from __future__ import annotations

import re

import numba
import numpy as np
import pytest

from marlcrash.sim import noalias
from marlcrash.sim.noalias import njit_noalias


def _scatter(x, idx, out_a, out_b):
    for k in range(idx.shape[0]):
        a = idx[k]
        for j in range(x.shape[1]):
            out_a[a, j] += x[k, j]
            out_b[a, j] -= 2.0 * x[k, j]


def test_noalias_is_active_with_this_numba_and_marks_the_array_arguments():
    """With the pinned numba the kernels get the mark (a numba upgrade that drops it fails here, not silently
    in the speed); the compiled function's array data pointers carry ``noalias`` in its LLVM IR, the plain
    ``numba.njit`` compilation of the same function has none."""
    assert noalias.ACTIVE, "numba's internals changed: the kernels run without noalias (module doc)"
    marked = njit_noalias()(_scatter)
    plain = numba.njit(_scatter)
    args = (np.ones((4, 8)), np.array([0, 1, 1, 2]), np.zeros((3, 8)), np.zeros((3, 8)))
    marked(*args)
    plain(*args)
    ir_marked = next(iter(marked.inspect_llvm().values()))
    ir_plain = next(iter(plain.inspect_llvm().values()))

    def marked_data(ir: str) -> set[str]:  # arrays whose data pointer (numba's 5th array field) is noalias
        define = next(ln for ln in ir.splitlines() if ln.startswith("define") and "_scatter" in ln)
        return set(re.findall(r"ptr noalias [^%,]*%arg\.(\w+)\.4\b", define))

    assert marked_data(ir_marked) == {"x", "idx", "out_a", "out_b"}
    assert marked_data(ir_plain) == set()


def test_noalias_function_gives_the_plain_numbers():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(50, 16))
    idx = rng.integers(0, 7, 50)
    outs = []
    for fn in (njit_noalias(fastmath=True)(_scatter), numba.njit(fastmath=True)(_scatter), _scatter):
        a, b = np.zeros((7, 16)), np.zeros((7, 16))
        fn(x, idx, a, b)
        outs.append((a, b))
    for a, b in outs[1:]:
        np.testing.assert_allclose(a, outs[0][0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b, outs[0][1], rtol=1e-12, atol=1e-12)


def test_without_numba_internals_njit_noalias_is_plain_njit(monkeypatch):
    monkeypatch.setattr(noalias, "ACTIVE", False)
    fn = njit_noalias(cache=False)(_scatter)
    assert type(fn) is type(numba.njit(_scatter))
    a, b = np.zeros((2, 3)), np.zeros((2, 3))
    fn(np.ones((2, 3)), np.array([0, 1]), a, b)
    assert a.sum() == pytest.approx(6.0) and b.sum() == pytest.approx(-12.0)
