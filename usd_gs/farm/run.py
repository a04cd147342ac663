"""A chunked (farm) run of ``usdgs process``: plan, resume, execute, stitch.

1. Shot-level step (serial, in this process): open the input, select the frames and
   estimate the lights once over the whole range (``ShotProcessor.shot_lights``), hash the
   options and the input layer stack.
2. Split the frames into chunks; chunks whose manifest entry matches (same frames, options,
   input, intact files) are skipped, everything else in the chunk folder that this module
   named (stale chunks, shot caches of other runs, temp files of a killed run) is removed.
3. Run the missing chunks on the chosen backend (``usd_gs.farm.executor``).
4. Stitch all chunks into the output as value clips (``usd_gs.farm.clips``; serial, cheap).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from usd_gs.farm.chunks import chunk_is_done, clean_folder, input_hash, options_hash, plan_chunks, read_sidecar
from usd_gs.farm.clips import assemble
from usd_gs.farm.executor import ChunkTask, make_backend, run_chunk, run_tasks
from usd_gs.pipeline.shot import ShotProcessor
from usd_gs.usd.lux import LIGHTS_ROOT

SHOT_FIRST_FRAME = "usdgs:shotFirstFrame"  # customData on /UsdGs/Lights written by ``usdgs lights``


def anchor_frame(stage, frames: list[float]) -> float:
    """The frame where a chunk estimates the avatars' normals (as the whole-shot run does at
    its first frame): the shot's first frame recorded by ``usdgs lights`` in the lights layer,
    else the first frame of this run (farm tasks must run on the lights layer to agree)."""

    prim = stage.GetPrimAtPath(LIGHTS_ROOT)
    value = prim.GetCustomDataByKey(SHOT_FIRST_FRAME) if prim else None
    return float(value) if value is not None else float(frames[0])


def default_clips_dir(output: str) -> str:
    """``<output stem>_clips/`` beside the output."""
    p = Path(output)
    return str(p.with_name(p.stem + "_clips"))


@dataclass
class FarmSummary:
    output: str
    clips_dir: str
    backend: str
    frames: list
    chunks: int
    computed: list
    skipped: list
    removed: list
    lights: list | None
    timings: dict
    results: list = field(default_factory=list)
    shot_warnings: list = field(default_factory=list)  # the shot-level step's (the light estimate's)

    @property
    def warnings(self) -> list[str]:
        """The shot-level step's warnings, then every chunk's, each once, in order."""
        return list(dict.fromkeys([*self.shot_warnings, *(w for r in self.results for w in r.warnings)]))

    def as_dict(self) -> dict:
        wall = self.timings.get("chunks", 0.0)
        return {"output": self.output, "clips_dir": self.clips_dir, "backend": self.backend,
                "frames": {"count": len(self.frames), "first": self.frames[0], "last": self.frames[-1]},
                "chunks": {"total": self.chunks, "computed": self.computed, "skipped": self.skipped,
                           "removed_stale": self.removed},
                "lights": None if self.lights is None else [lt.name for lt in self.lights],
                "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
                "frames_per_second": round(sum(len(r.frames) for r in self.results) / wall, 3) if wall else None,
                "chunk_seconds": {r.name: round(r.seconds, 4) for r in self.results},
                "shot_cache": {r.name: r.shot_cache for r in self.results}, "warnings": self.warnings}


def run_farm(input_path: str, output: str, options, chunk_size: int, clips_dir: str | None = None,
             workers: int | None = None, scheduler: str | None = None, client=None, retries: int = 2,
             report=None, fn=run_chunk) -> FarmSummary:
    """The steps of the module docstring; ``fn`` is the chunk function (tests inject failures)."""

    t0 = time.perf_counter()
    timings = {}
    folder = Path(clips_dir or default_clips_dir(output)).absolute()
    folder.mkdir(parents=True, exist_ok=True)
    opts = options  # ShotProcessor does not modify its options
    shot = ShotProcessor(input_path, output, opts)
    lights = shot.shot_lights()
    frames = shot.frames
    anchor = anchor_frame(shot.stage, frames)
    o_hash, i_hash = options_hash(opts, lights, anchor), input_hash(shot.stage)
    shot_warnings = list(shot.warnings)
    del shot
    chunks = plan_chunks(frames, chunk_size)
    t = time.perf_counter()
    timings["shot"] = t - t0
    done = [c for c in chunks if chunk_is_done(c, folder, o_hash, i_hash)]
    keep = {c.name for c in done}
    removed = clean_folder(folder, chunks, keep, o_hash, i_hash)
    todo = [c for c in chunks if c.name not in keep]
    tasks = [ChunkTask(str(Path(input_path).absolute()), str(folder), c, opts, lights, anchor, o_hash, i_hash)
             for c in todo]
    if report and done:
        report(f"{len(done)} of {len(chunks)} chunk(s) already finished, skipped")
    backend = make_backend(fn, workers, scheduler, client) if tasks else None
    name = backend.name if backend else "none"
    try:
        t = time.perf_counter()
        results = run_tasks(tasks, backend, retries=retries, report=report, total=len(chunks)) if tasks else []
        timings["chunks"] = time.perf_counter() - t
    finally:
        if backend:
            backend.close()
    t = time.perf_counter()

    entries = []
    for c in chunks:
        e = read_sidecar(c.sidecar_path(folder))
        e["path"] = str(c.layer_path(folder))
        entries.append(e)
    assemble(folder, output, entries)
    timings["assemble"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t0
    return FarmSummary(str(output), str(folder), name, frames, len(chunks), [c.name for c in todo],
                       [c.name for c in done], removed, lights, timings, results, shot_warnings)
