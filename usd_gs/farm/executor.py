"""Running frame chunks: in this process, in local worker processes, or on a dask.distributed
scheduler, with per-chunk progress and retries.

Every backend runs the same picklable :func:`run_chunk` on a :class:`ChunkTask`; it writes
the chunk's layer (``ShotProcessor`` over the chunk's frames, with the shot-level lights and
normals anchor frame), sets the layer's own start and end time codes and writes the
sidecar last (``usd_gs.farm.chunks``). A failed chunk is resubmitted up to ``retries``
times; a chunk that still fails stops the run with :class:`ChunkFailed` naming the chunk
and its frames. A ``UserError`` (bad input or options) is not retried.

``--scheduler`` needs the optional ``distributed`` package (``pip install usd-gs[farm]``);
the chunk folder must then be on a file system every worker sees.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace
from pathlib import Path

from pxr import Sdf

from usd_gs.errors import UserError
from usd_gs.farm.chunks import FORMAT, Chunk, sha256_file, shot_cache_key, shot_cache_path, write_json_atomic
from usd_gs.pipeline.shot import ShotProcessor
from usd_gs.pipeline.shot_cache import ShotCache
from usd_gs.usd.gaussian_prim import save_stage_atomic

# Numba's default (workqueue) threading layer must not be entered from two threads at once;
# chunks that share a process (dask workers with several threads, processes=False) take turns.
_PROCESS_LOCK = threading.Lock()


class ChunkFailed(RuntimeError):
    """A chunk failed more often than the retry limit allows."""

@dataclass
class ChunkTask:
    """Everything a worker needs to compute one chunk (picklable)."""

    input_path: str
    folder: str
    chunk: Chunk
    options: object  # ProcessOptions
    lights: list | None  # shot-level lights (None: per frame from the stage)
    anchor_frame: float
    options_hash: str
    input_hash: str


@dataclass
class ChunkResult:
    name: str
    frames: list
    seconds: float
    timings: dict
    worker: str
    started: float = 0.0
    warnings: list = field(default_factory=list)
    shot_cache: dict = field(default_factory=dict)  # {"loaded": n, "computed": n} entries of the shared cache


def run_chunk(task: ChunkTask) -> ChunkResult:
    """Compute one chunk into ``task.folder`` (see the module docstring). Safe to run twice."""

    t0 = time.perf_counter()
    started = time.time()
    folder = Path(task.folder)
    chunk = task.chunk
    layer_path = chunk.layer_path(folder)
    opts = replace(task.options, frames=chunk.frames_spec())
    cache = ShotCache(shot_cache_path(folder, task.options_hash, task.input_hash),
                      shot_cache_key(task.options_hash, task.input_hash))
    with _PROCESS_LOCK:
        proc = ShotProcessor(task.input_path, str(layer_path), opts, lights=task.lights,
                             anchor_frame=task.anchor_frame, shot_cache=cache)
        summary = proc.run(progress=False)
        # the chunk layer's own range (clips contribute time samples of this range only)
        layer = Sdf.Layer.FindOrOpen(str(layer_path))
        layer.startTimeCode, layer.endTimeCode = chunk.frames[0], chunk.frames[-1]
        save_stage_atomic(layer, layer_path)
        del layer
    entry = {"format": FORMAT, "layer": layer_path.name, "frames": list(chunk.frames),
             "options_hash": task.options_hash, "input_hash": task.input_hash,
             "layer_sha256": sha256_file(layer_path), "probe_files": summary.probe_files,
             "input": os.path.abspath(task.input_path), "seconds": round(time.perf_counter() - t0, 4)}
    write_json_atomic(chunk.sidecar_path(folder), entry)
    return ChunkResult(chunk.name, list(chunk.frames), time.perf_counter() - t0, dict(summary.timings),
                       f"{os.uname().nodename}:{os.getpid()}", started, list(summary.warnings),
                       {"loaded": cache.loaded, "computed": cache.computed})


def _worker_init(threads: int) -> None:
    """Process-pool worker start: one numba thread share per worker unless the user chose, and the
    allocator set up for a batch run (``usd_gs.pipeline.allocator``)."""
    os.environ.setdefault("NUMBA_NUM_THREADS", str(threads))
    from usd_gs.pipeline.allocator import tune_for_batch

    tune_for_batch()


# ---------------------------------------------------------------------- backends
class InlineBackend:
    """Runs chunks one after the other in this process (no start-up cost)."""

    name = "inline"

    def __init__(self, fn):
        self.fn = fn

    def submit(self, task):
        from concurrent.futures import Future

        fut = Future()
        try:
            fut.set_result(self.fn(task))
        except BaseException as exc:  # noqa: BLE001 - handed to the retry loop
            if isinstance(exc, KeyboardInterrupt):
                raise
            fut.set_exception(exc)
        return fut

    def wait(self, futures):
        return list(futures), set()

    def close(self):
        pass


class LocalBackend:
    """``workers`` local processes (spawned: nothing of this process's USD or numba state is
    forked); a worker that dies breaks the pool, which is rebuilt for the retries."""

    def __init__(self, fn, workers: int):
        import multiprocessing

        self.fn, self.workers = fn, workers
        self.name = f"{workers} local process(es)"
        self._ctx = multiprocessing.get_context("spawn")
        self._threads = max(1, (os.cpu_count() or 1) // workers)
        self._pool = None

    def _ensure(self):
        if self._pool is None:
            self._pool = ProcessPoolExecutor(self.workers, mp_context=self._ctx, initializer=_worker_init,
                                             initargs=(self._threads,))
        return self._pool

    def submit(self, task):
        try:
            return self._ensure().submit(self.fn, task)
        except BrokenProcessPool:
            self._pool = None
            return self._ensure().submit(self.fn, task)

    def wait(self, futures):
        done, pending = wait(futures, return_when=FIRST_COMPLETED)
        if self._pool is not None and any(isinstance(f.exception(), BrokenProcessPool) for f in done):
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
        return list(done), pending

    def close(self):
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


class DaskBackend:
    """Chunks as tasks of a dask.distributed ``Client`` (a running scheduler's address, or a
    client the caller made, e.g. on a ``LocalCluster``)."""

    def __init__(self, fn, scheduler=None, client=None):
        try:
            import distributed
        except ImportError:
            raise UserError("--scheduler needs the 'distributed' package: pip install 'usd-gs[farm]'") from None
        self._distributed = distributed
        self.fn = fn
        self._own = client is None
        if client is None:
            try:
                client = distributed.Client(scheduler, timeout="20s")
            except OSError as exc:
                raise UserError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
        self.client = client
        self.name = f"dask scheduler {client.scheduler.address}"
        self._n = 0

    def submit(self, task):
        self._n += 1
        return self.client.submit(self.fn, task, key=f"usdgs-{task.chunk.name}-{self._n}", pure=False)

    def wait(self, futures):
        res = self._distributed.wait(list(futures), return_when="FIRST_COMPLETED")
        return list(res.done), set(res.not_done)

    def close(self):
        if self._own:
            self.client.close()


def make_backend(fn=run_chunk, workers: int | None = None, scheduler: str | None = None, client=None):
    if scheduler or client is not None:
        return DaskBackend(fn, scheduler, client)
    if workers:
        if workers < 1:
            raise UserError(f"--workers must be >= 1, got {workers}")
        return LocalBackend(fn, workers)
    return InlineBackend(fn)


def _describe(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {' '.join(str(exc).split()) or type(exc).__name__}"


def run_tasks(tasks: list[ChunkTask], backend, retries: int = 2, report: Callable[[str], None] | None = None,
              total: int | None = None) -> list[ChunkResult]:
    """Run ``tasks`` on ``backend``; each failed task is resubmitted up to ``retries`` times.
    ``report`` gets one progress line per finished or failed chunk. Returns the results in
    completion order; raises ``ChunkFailed`` (or the chunk's ``UserError``) naming the chunk."""
    total = total or len(tasks)
    attempts = {t.chunk.name: 0 for t in tasks}
    running = {}
    results = []

    def start(task):
        attempts[task.chunk.name] += 1
        running[backend.submit(task)] = task

    try:
        for t in tasks:
            start(t)
        while running:
            done, _ = backend.wait(set(running))
            for fut in done:
                task = running.pop(fut)
                c = task.chunk
                exc = fut.exception()
                if exc is None:
                    r = fut.result()
                    results.append(r)
                    if report:
                        report(f"chunk {c.index + 1}/{total} ({c.label}) done in {r.seconds:.2f} s on {r.worker}")
                    continue
                if isinstance(exc, UserError):
                    raise UserError(f"chunk {c.name} ({c.label}): {_one_line(exc)}") from exc
                n = attempts[c.name]
                if n > retries:
                    raise ChunkFailed(f"chunk {c.name} ({c.label}) failed {n} time(s); last error: {_describe(exc)}")
                if report:
                    report(f"chunk {c.index + 1}/{total} ({c.label}) failed (attempt {n}/{retries + 1}): "
                           f"{_describe(exc)}; retrying")
                start(task)
    finally:
        for fut in running:
            fut.cancel()
    return results


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def stderr_report(line: str) -> None:
    print(f"usdgs farm: {line}", file=sys.stderr, flush=True)
