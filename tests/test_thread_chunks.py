"""Thread-parallel kernel ranges (numba_kernels.thread_chunks)."""

import numba
import numpy as np
import pytest

from numba_kernels.thread_chunks import run_chunks


@pytest.mark.parametrize("threads", [1, 2])
def test_ranges_cover_every_index_once(threads):
    old = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        for n, min_chunk in ((1, 1), (7, 1), (1000, 1), (1000, 300), (0, 1)):
            hits = np.zeros(n, np.int64)

            def kernel(lo, hi, out):
                out[lo:hi] += 1

            run_chunks(kernel, n, hits, min_chunk=min_chunk)
            assert np.all(hits == 1), (n, min_chunk)
    finally:
        numba.set_num_threads(old)


def test_errors_in_a_range_reach_the_caller():
    def kernel(lo, hi):
        if lo <= 5 < hi:
            raise ValueError("bad range")

    with pytest.raises(ValueError, match="bad range"):
        run_chunks(kernel, 100)


def test_rasteriser_output_does_not_depend_on_the_thread_count():
    """The converted kernels write disjoint outputs: 1 and 2 threads give identical images."""
    from usd_gs.render.rasterize import render_cube_faces
    from usd_gs.synthetic import random_gaussians

    g = random_gaussians(3000, 3, seed=4)
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = render_cube_faces(g, (0.0, 0.0, 0.0), 24)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        b = render_cube_faces(g, (0.0, 0.0, 0.0), 24)
    finally:
        numba.set_num_threads(old)
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x, y)
    assert a[1].min() < 0.9  # something was drawn


def test_a_task_takes_its_share_of_the_threads(monkeypatch):
    """Inside tasks run side by side (``as_task``) a kernel gets numba's thread count over the tasks
    running at its call (at least 1): the count of three running tasks, then of the last one alone."""
    import threading

    from numba_kernels.thread_chunks import as_task, thread_count

    monkeypatch.setattr(numba, "get_num_threads", lambda: 16)
    assert thread_count() == 16  # outside any task: numba's count
    started, recorded, others_done = threading.Barrier(3), threading.Barrier(3), threading.Event()
    seen: dict = {}

    def work(name):
        started.wait()
        seen[name] = [thread_count()]
        recorded.wait()  # (none finishes before all three counted)
        if name == "last":
            others_done.wait()
            seen[name].append(thread_count())
        return name

    tasks = {name: as_task(lambda name=name: work(name)) for name in ("a", "b", "last")}
    threads = {name: threading.Thread(target=t) for name, t in tasks.items()}
    for t in threads.values():
        t.start()
    threads["a"].join()
    threads["b"].join()
    others_done.set()
    threads["last"].join()
    assert seen == {"a": [5], "b": [5], "last": [5, 16]}  # 16 // 3, then 16 // 1
    assert thread_count() == 16
    assert tasks["a"].__wrapped__ is not None


def test_a_task_beside_another_runs_its_ranges_in_its_own_thread(monkeypatch):
    """Two threads and two tasks running: each task's share is one thread, so ``run_chunks`` runs
    every range in the task's own thread (no hand-off through the pool)."""
    import threading

    from numba_kernels.thread_chunks import as_task

    monkeypatch.setattr(numba, "get_num_threads", lambda: 2)
    both = threading.Barrier(2)
    calls: dict = {}

    def kernel(lo, hi, name):
        calls.setdefault(name, []).append((lo, hi, threading.get_ident()))

    def work(name):
        both.wait()
        run_chunks(kernel, 1000, name)
        both.wait()  # (neither finishes before the other's call ran)
        return threading.get_ident()

    idents = {}
    threads = [threading.Thread(target=lambda n=n: idents.__setitem__(n, as_task(lambda: work(n))())) for n in "xy"]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    step = [(lo, lo + 125) for lo in range(0, 1000, 125)]  # 2 threads x 4 ranges each
    assert {n: sorted((lo, hi) for lo, hi, _ in c) for n, c in calls.items()} == {"x": step, "y": step}
    assert all(ident == idents[n] for n in "xy" for _, _, ident in calls[n])


def test_when_a_task_ends_a_helper_joins_the_call_still_running(monkeypatch):
    """Task a's call starts while task b runs (share one: no helper); b ends with no task waiting,
    and a helper from the pool takes some of a's ranges while a's own thread is busy with its first."""
    import threading

    from numba_kernels.thread_chunks import as_task

    monkeypatch.setattr(numba, "get_num_threads", lambda: 2)
    both, a_open, helped = threading.Barrier(2), threading.Event(), threading.Event()
    owner, ran = {}, []

    def kernel(lo, hi):
        ran.append((lo, threading.get_ident()))
        if threading.get_ident() != owner["a"]:
            helped.set()
        if lo == 0:
            a_open.set()
            assert helped.wait(10), "no helper joined"

    def a():
        owner["a"] = threading.get_ident()
        both.wait()
        run_chunks(kernel, 800)

    def b():
        both.wait()
        assert a_open.wait(10)

    tasks = [as_task(a), as_task(b)]
    threads = [threading.Thread(target=t) for t in tasks]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(lo for lo, _ in ran) == list(range(0, 800, 100))  # every range once
    assert {ident for _, ident in ran} - {owner["a"]}  # some ran in a helper


def test_errors_in_a_task_range_reach_the_task(monkeypatch):
    from numba_kernels.thread_chunks import as_task

    monkeypatch.setattr(numba, "get_num_threads", lambda: 2)

    def kernel(lo, hi):
        if lo <= 5 < hi:
            raise ValueError("bad range")

    with pytest.raises(ValueError, match="bad range"):
        as_task(lambda: run_chunks(kernel, 100))()


def test_a_task_takes_the_numba_thread_count_of_the_thread_that_queued_it():
    import threading

    from numba_kernels.thread_chunks import as_task

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one CPU thread here: every thread's count is 1")
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        task = as_task(numba.get_num_threads)
    finally:
        numba.set_num_threads(before)
    seen = []
    t = threading.Thread(target=lambda: seen.append((numba.get_num_threads(), task())))
    t.start()
    t.join()
    assert seen == [(numba.config.NUMBA_NUM_THREADS, 1)]  # a new thread's own count, then the queuer's
