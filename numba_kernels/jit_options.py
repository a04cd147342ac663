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

import numpy as np
from numba.core.errors import NumbaPerformanceWarning

#: Why some kernels marked ``# serial`` have no ``prange``: a parallel kernel costs about twice the
#: compile time of the same loop run serially (numba types the loop body again as an outlined
#: gufunc and LLVM optimises all linked code once more), paid on every cold run, while these
#: kernels take milliseconds per call (docs/design.md, "Compile time").
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
    :func:`prange_only` although the kernel has no ``prange``: the parallel pipeline's passes
    make the serial code faster for a little more compile time, much less than a ``prange``
    loop's (its body is typed again as a gufunc; docs/design.md, "Compile time"). numba warns
    that nothing could be parallelised; that warning is filtered for these kernels (below)."""
    return {"nogil": True, "parallel": prange_only()}


def read_only(x: np.ndarray) -> np.ndarray:
    """A read-only view of ``x`` for a kernel call: the kernel sees one array type whether or not the
    caller's array is writeable (numba compiles a read-only array as a type of its own, a second
    specialisation to compile and cache)."""
    v = x.view()
    v.flags.writeable = False
    return v


def float_rows(x) -> np.ndarray:
    """``x`` as a C-contiguous (N, 3) array of float32 or float64 (other dtypes widened to float64; no
    copy when it is one already): the kernels take either width, one specialisation each."""
    v = np.asarray(x)
    if v.dtype not in (np.float32, np.float64):
        v = v.astype(np.float64)
    return np.ascontiguousarray(v).reshape(-1, 3)


warnings.filterwarnings("ignore", message=r"(?s).*The keyword argument 'parallel=True' was specified but no "
                        r"transformation for parallel execution was possible", category=NumbaPerformanceWarning)
