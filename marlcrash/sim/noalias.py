"""``njit_noalias``: numba functions whose array arguments LLVM may assume do not overlap (C's ``restrict``).

Why: the fast kernels' inner loops run over the lanes of a chunk (SIMD vectors) and write several arrays per
link (link force, plastic work, both end nodes' force sums). LLVM cannot prove that numba arrays do not overlap,
so it guards every such vector loop with a runtime overlap test of each pair of arrays it touches, once per link,
about a hundred scalar instructions in front of a loop of four to eight vector iterations. Marked ``noalias``,
the pointers of different arguments are known to be distinct and the tests disappear. The simulation kernel's
per-chunk function ran 1.42x (float64) and 1.83x (float32) as fast as the same code compiled without the mark, the
roofline's link pass 1.37-1.38x (default car, ``B = 1024``, 2 threads, interleaved in one run:
``benchmarks/bench_noalias.py [--float32]``).

numba has this switch (``Flags.noalias``: its parallel-loop lowering sets it when it finds no aliases) but no
decorator option for it; :func:`njit_noalias` compiles with it set, through a target whose options class sets the
flag. Everything else (typing, target context, caching) is numba's CPU target's.

The promise is the caller's: no two array arguments of a ``njit_noalias`` function may share memory that one of
them writes. The kernels pass separately allocated arrays (or views of different arrays) only. If the numba
internals this relies on are missing (another numba version), :func:`njit_noalias` falls back to plain
``numba.njit`` (same numbers, without the speed-up) and :data:`ACTIVE` says so.
"""

from __future__ import annotations

import numba

__all__ = ["ACTIVE", "njit_noalias"]

try:
    from numba.core import cpu
    from numba.core.registry import CPUDispatcher, CPUTarget, cpu_target

    class _NoAliasOptions(cpu.CPUTargetOptions):
        def finalize(self, flags, options):
            super().finalize(flags, options)
            flags.noalias = True

    class _NoAliasTarget(CPUTarget):
        options = _NoAliasOptions

        @property
        def target_context(self):
            return cpu_target.target_context

        @property
        def typing_context(self):
            return cpu_target.typing_context

    class _NoAliasDispatcher(CPUDispatcher):
        targetdescr = _NoAliasTarget("cpu")

    ACTIVE = True
except (ImportError, AttributeError, TypeError):  # pragma: no cover - depends on numba's internals
    ACTIVE = False


def njit_noalias(cache: bool = False, **options):
    """Like ``numba.njit(cache=..., **options)``, with every array argument marked ``noalias`` (module doc)."""

    def decorate(fn):
        if not ACTIVE:  # pragma: no cover
            return numba.njit(cache=cache, **options)(fn)
        disp = _NoAliasDispatcher(fn, targetoptions={"nopython": True, **options})
        if cache:
            disp.enable_caching()
        return disp

    return decorate
