"""Parallel loops as Python threads over serial ``nogil`` kernels (no numba parfors).

A ``prange`` loop costs compile time on every cold run: numba types the loop body a second
time as an outlined gufunc and optimises the linked code again (docs/design.md, "Compile
time"). The same parallelism
comes from running a serial kernel compiled with ``nogil=True`` on index ranges in a few
threads: :func:`run_chunks` splits ``range(n)`` into ``chunks_per_thread`` x threads
contiguous ranges and calls ``kernel(lo, hi, *args)`` on each, the calling thread and helpers
from a shared thread pool taking the next range until none is left (uneven ranges balance out).
Each range must write disjoint outputs, so the result does not depend on the thread count or
the schedule.

The thread count is numba's (``numba.get_num_threads()``: ``NUMBA_NUM_THREADS``, or
``numba.set_num_threads``); with one thread, or one range, the kernel runs in the calling
thread. Inside a task that runs beside others (:func:`as_task`: the main job's shadow pass runs
its tasks in that many threads) a call's helpers are its share of the threads, that count over
the tasks running at the call, less one (the task's own thread): while the tasks fill the
threads each task runs its ranges in its own thread (no hand-offs through the pool, whose
threads would only queue behind each other's), and when a task ends with no task waiting to
start, a helper joins the call with the most ranges left, so the last tasks of a pass spread
over the threads the finished ones left.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

_POOL: list = [None, 0]  # executor, its size
_LOCK = threading.Lock()
_TASKS_LOCK = threading.Lock()  # guards the three below
_RUNNING = [0]  # as_task tasks running now
_WAITING = [0]  # as_task tasks made but not started yet
_OPEN: list = []  # the _Ranges of the run_chunks calls inside tasks, while they run
_IN_TASK = threading.local()  # .task: the current thread runs an as_task task


def _pool(threads: int) -> ThreadPoolExecutor:
    with _LOCK:
        if _POOL[0] is None or _POOL[1] != threads:
            if _POOL[0] is not None:
                _POOL[0].shutdown(wait=False)
            _POOL[0] = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="usdgs-kernel")
            _POOL[1] = threads
        return _POOL[0]


def _numba_threads() -> int:
    import numba

    return max(1, int(numba.get_num_threads()))


def thread_count() -> int:
    """Threads a kernel called now may use: numba's setting, or inside an :func:`as_task` task
    its share (module doc)."""
    n = _numba_threads()
    if getattr(_IN_TASK, "task", False):
        return max(1, n // max(1, _RUNNING[0]))
    return n


class _Ranges:
    """The ranges of one :func:`run_chunks` call, each taken once, by the calling thread or a
    helper, until none is left; ``finished`` is set when every range has run."""

    def __init__(self, kernel, bounds: list, args: tuple):
        self.kernel, self.bounds, self.args = kernel, bounds, args
        self.errors: list = []
        self.finished = threading.Event()
        self._lock = threading.Lock()
        self._next = self._done = 0

    def left(self) -> int:
        """Ranges not taken yet."""
        return len(self.bounds) - self._next

    def work(self) -> None:
        """Run ranges until none is left to take."""
        while True:
            with self._lock:
                if self._next >= len(self.bounds):
                    return
                lo, hi = self.bounds[self._next]
                self._next += 1
            try:
                self.kernel(lo, hi, *self.args)
            except BaseException as e:  # (re-raised by the caller)
                self.errors.append(e)
            finally:
                with self._lock:
                    self._done += 1
                    if self._done == len(self.bounds):
                        self.finished.set()


def _help_open_calls() -> None:
    """A helper's work after a task ended: the ranges of the running calls, the call with the
    most left first, until no call has any left."""
    while True:
        with _TASKS_LOCK:
            calls = [r for r in _OPEN if r.left() > 0]
        if not calls:
            return
        max(calls, key=_Ranges.left).work()


def as_task(fn):
    """``fn`` (a callable without arguments) as one of several tasks run side by side in threads,
    made when the task is queued (its thread takes the queuing thread's numba thread count, which
    numba keeps per thread): while it runs it counts among the running tasks and the calls of
    :func:`run_chunks` in it take their share of the threads; when it ends with no task waiting,
    a helper joins the running calls (module doc). The results do not depend on it (each range
    writes disjoint outputs)."""
    threads = _numba_threads()  # the queuing thread's setting, for the task's thread too
    with _TASKS_LOCK:
        _WAITING[0] += 1

    def task():
        if _numba_threads() != threads:
            import numba

            numba.set_num_threads(threads)
        with _TASKS_LOCK:
            _WAITING[0] -= 1
            _RUNNING[0] += 1
        outer = getattr(_IN_TASK, "task", False)
        _IN_TASK.task = True
        try:
            return fn()
        finally:
            _IN_TASK.task = outer
            with _TASKS_LOCK:
                _RUNNING[0] -= 1
                free = _WAITING[0] == 0 and any(r.left() > 0 for r in _OPEN)
            if free:  # this thread's core is free: help the calls still running
                _pool(_numba_threads()).submit(_help_open_calls)

    task.__wrapped__ = fn
    return task


def run_chunks(kernel, n: int, *args, chunks_per_thread: int = 4, min_chunk: int = 1, threads: bool = True) -> None:
    """Call ``kernel(lo, hi, *args)`` for contiguous ranges covering ``0..n-1`` (module doc);
    ranges hold at least ``min_chunk`` items. Exceptions raised in a range are re-raised (the
    first, after every range ran). ``threads`` False: the whole range in the calling thread (for
    a caller that runs beside kernel-heavy threads, e.g. the output authoring beside the next
    frame's shadow tasks, whose ranges would otherwise queue behind theirs)."""
    n = int(n)
    if n <= 0:
        return
    total = _numba_threads() if threads else 1
    parts = max(1, min(total * chunks_per_thread, n // max(1, min_chunk)))
    if total == 1 or parts == 1:
        kernel(0, n, *args)
        return
    step = (n + parts - 1) // parts
    call = _Ranges(kernel, [(lo, min(n, lo + step)) for lo in range(0, n, step)], args)
    in_task = getattr(_IN_TASK, "task", False)
    if in_task:
        with _TASKS_LOCK:
            _OPEN.append(call)
    try:
        helpers = min(thread_count(), len(call.bounds)) - 1
        if helpers > 0:
            pool = _pool(total)
            for _ in range(helpers):
                pool.submit(call.work)
        call.work()
        call.finished.wait()
    finally:
        if in_task:
            with _TASKS_LOCK:
                _OPEN.remove(call)
    if call.errors:
        raise call.errors[0]
