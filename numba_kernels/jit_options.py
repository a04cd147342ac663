"""Shared numba options that cut compile time without changing results.

``PRANGE_ONLY``-style parallelism: numba's ``parallel=True`` also rewrites NumPy calls, array
expressions, slice assignments and reductions inside the kernel into extra parallel loops
("parfors"), each one outlined and compiled as a separate gufunc. The kernels here parallelise
only through explicit ``prange`` loops and allocate their work arrays with ``np.empty`` /
``np.zeros``, so those rewrites only make compilation slower (measured: ``rasterize._blend``
3.9 s -> 2.4 s of its own compile time) and the allocations run serially either way.

The kernels of the main job's hot path go further and have no ``prange`` at all
(:func:`threaded`): ``numba_kernels.thread_chunks.run_chunks`` runs them on index ranges in a
thread pool, which saves the second typing of every parallel loop body (cold-cache compile of
the shadow-map kernels 13.5 -> 8 s, of the relighting 16.3 -> 13 s).
"""

from __future__ import annotations

import warnings

from numba.core.errors import NumbaPerformanceWarning

#: Why some kernels marked ``# serial`` have no ``prange``: a parallel kernel costs about twice the
#: compile time of the same loop run serially (numba types the loop body again as an outlined
#: gufunc and LLVM optimises all linked code once more), 0.4-1.3 s each, paid on every cold run.
#: These kernels take milliseconds per call on the demo (measured with one thread over 12 frames:
#: transfer scale 1.7 ms, probe normal equations 1.4 ms, SH relight 0.14 ms, normal rotation 1.2 ms,
#: tile binning 2.7 ms per call; the light-estimation grid queries and base scores < 10 ms once),
#: so a second thread would save less than 0.1 s per 12 frames.
SERIAL_NOTE = "serial kernels: compile time outweighs their parallel speed-up (see module comment)"


def prange_only() -> dict:
    """A fresh ``parallel=`` option dict for ``@njit``: only ``prange`` loops run in parallel.

    A new dict per call because numba consumes (pops) the dict it is given.
    """
    return {"prange": True, "numpy": False, "setitem": False, "reduction": False, "comprehension": False,
            "inplace_binop": False, "stencil": False, "fusion": False}


def threaded() -> dict:
    """``@njit`` options of a kernel that ``thread_chunks.run_chunks`` runs on index ranges in
    threads: ``nogil`` (the threads run at once) and numba's parallel pipeline with
    :func:`prange_only` although the kernel has no ``prange``. Measured with one thread on the
    DGSM bench (``NUMBA_NUM_THREADS=1 benchmarks/bench_dgsm.py``): build 0.243 s as plain
    ``nogil`` kernels, 0.209-0.232 s with the parallel pipeline's passes, for ~0.2 s more compile
    per kernel, while a ``prange`` loop costs ~1.5 s more (its body is typed again as a gufunc).
    numba warns that nothing could be
    parallelised; that warning is filtered for these kernels (below)."""
    return {"nogil": True, "parallel": prange_only()}


warnings.filterwarnings("ignore", message=r"(?s).*The keyword argument 'parallel=True' was specified but no "
                        r"transformation for parallel execution was possible", category=NumbaPerformanceWarning)
