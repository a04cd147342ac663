"""The main job: options, the per-shot processor (``ShotProcessor``), its summary and the JIT warm-up.

Public names are re-exported lazily (``usd_gs._lazy``): ``from usd_gs.pipeline import X`` imports only
the module that defines ``X``.
"""

from usd_gs._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "WarmUp": "jit_warmup",
    "cache_is_cold": "jit_warmup",
    "start": "jit_warmup",
    "stop": "jit_warmup",
    "wait_for": "jit_warmup",
    "warm_up": "jit_warmup",
    "ProcessOptions": "options",
    "dgsm_config": "options",
    "load_config": "options",
    "process_kwargs": "options",
    "ProcessSummary": "shot",
    "ShotProcessor": "shot",
    "default_output_path": "shot",
})
