"""Farm runs: frame chunks and their manifest, value-clip stitching, executors (local processes, dask) and the
chunked run.

Public names are re-exported lazily (``usd_gs._lazy``): ``from usd_gs.farm import X`` imports only
the module that defines ``X``.
"""

from usd_gs._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "Chunk": "chunks",
    "chunk_is_done": "chunks",
    "clean_folder": "chunks",
    "entry_files_ok": "chunks",
    "input_hash": "chunks",
    "options_hash": "chunks",
    "plan_chunks": "chunks",
    "read_sidecar": "chunks",
    "remove_chunk": "chunks",
    "sha256_file": "chunks",
    "write_json_atomic": "chunks",
    "AssembleSummary": "clips",
    "assemble": "clips",
    "collect_chunks": "clips",
    "ChunkFailed": "executor",
    "ChunkResult": "executor",
    "ChunkTask": "executor",
    "DaskBackend": "executor",
    "InlineBackend": "executor",
    "LocalBackend": "executor",
    "make_backend": "executor",
    "run_chunk": "executor",
    "run_tasks": "executor",
    "stderr_report": "executor",
    "FarmSummary": "run",
    "anchor_frame": "run",
    "default_clips_dir": "run",
    "run_farm": "run",
})
