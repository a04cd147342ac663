"""Parallel loops as Python threads over serial ``nogil`` kernels (no numba parfors).

A ``prange`` loop costs compile time on every cold run: numba types the loop body a second
time as an outlined gufunc and optimises the linked code again (docs/design.md, "Compile
time"). The same parallelism
comes from running a serial kernel compiled with ``nogil=True`` on index ranges in a few
threads: :func:`run_chunks` splits ``range(n)`` into ``chunks_per_thread`` x threads
contiguous ranges and calls ``kernel(lo, hi, *args)`` on each from a shared thread pool
(dynamic assignment: uneven ranges balance out). Each range must write disjoint outputs, so
the result does not depend on the thread count or the schedule.

The thread count is numba's (``numba.get_num_threads()``: ``NUMBA_NUM_THREADS``, or
``numba.set_num_threads``); with one thread, or one range, the kernel runs in the calling
thread.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

_POOL: list = [None, 0]  # executor, its size
_LOCK = threading.Lock()


def _pool(threads: int) -> ThreadPoolExecutor:
    with _LOCK:
        if _POOL[0] is None or _POOL[1] != threads:
            if _POOL[0] is not None:
                _POOL[0].shutdown(wait=False)
            _POOL[0] = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="usdgs-kernel")
            _POOL[1] = threads
        return _POOL[0]


def thread_count() -> int:
    """Threads the kernels may use (numba's setting)."""
    import numba

    return max(1, int(numba.get_num_threads()))


def run_chunks(kernel, n: int, *args, chunks_per_thread: int = 4, min_chunk: int = 1, threads: bool = True) -> None:
    """Call ``kernel(lo, hi, *args)`` for contiguous ranges covering ``0..n-1`` (module doc);
    ranges hold at least ``min_chunk`` items. Exceptions raised in a range are re-raised.
    ``threads`` False: the whole range in the calling thread (for a caller that runs beside
    kernel-heavy threads, e.g. the output authoring beside the next frame's shadow tasks, whose
    ranges would otherwise queue behind theirs)."""
    n = int(n)
    if n <= 0:
        return
    count = thread_count() if threads else 1
    parts = max(1, min(count * chunks_per_thread, n // max(1, min_chunk)))
    if count == 1 or parts == 1:
        kernel(0, n, *args)
        return
    step = (n + parts - 1) // parts
    bounds = [(lo, min(n, lo + step)) for lo in range(0, n, step)]
    futures = [_pool(count).submit(kernel, lo, hi, *args) for lo, hi in bounds]
    for f in futures:
        f.result()
