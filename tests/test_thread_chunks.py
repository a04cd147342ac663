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
