"""Memory-allocator settings for a batch process (``usdgs process``, a farm worker).

A frame allocates and frees many large numpy buffers (the packed occluders of each DGSM, the
rasteriser's per-Gaussian masks and records, atlas indices: tens of MB each). With glibc's
defaults every buffer above the dynamic mmap threshold (at most 32 MiB) is a fresh mapping that
is unmapped when freed, and freed memory at the top of the heap is returned to the system, so
each such buffer faults all its pages in again (the kernel zeroes every one). numpy also advises
huge pages (``MADV_HUGEPAGE``) on buffers of 4 MiB and more; where the kernel's transparent
huge page ``defrag`` setting is ``madvise`` (the Debian and Ubuntu default), a fault in such a
region can stall on synchronous memory compaction when no huge page is free (numpy issue
#31590): on a shot with a large static scene these stalls came and went from run to run.

:func:`tune_for_batch` therefore, for the rest of the process:

- raises glibc's ``M_MMAP_THRESHOLD`` to 1 GiB and ``M_TRIM_THRESHOLD`` to 2 GiB - 1, so freed
  buffers stay in the heap and the next frame's reuse them without faulting (the process keeps
  its peak heap until it exits; the peak itself is what the run needed anyway);
- turns numpy's huge-page advice off (plain pages; no compaction stall): through numpy's own
  switch where numpy is imported already, else through ``NUMPY_MADVISE_HUGEPAGE=0`` in this
  process's environment (which processes it starts inherit).

Each setting is left alone where the user chose it (the environment variables
``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_``, ``NUMPY_MADVISE_HUGEPAGE``), and all of
them with ``USDGS_ALLOCATOR=default`` (``batch``, or unset: these settings; any other value is a
``UserError``). Off glibc (macOS, musl) only the numpy setting applies. Values do not change,
only where memory comes from.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

from usd_gs.errors import UserError

#: glibc's mallopt parameters (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 1 << 30
TRIM_THRESHOLD = (1 << 31) - 1
#: environment variable that turns :func:`tune_for_batch` off (value ``default``)
ENV = "USDGS_ALLOCATOR"


def _libc():
    """glibc's ``mallopt`` holder, or None where the C library is not glibc."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.gnu_get_libc_version  # noqa: B018 - only glibc has it
    except (OSError, AttributeError):
        return None
    return libc


def tune_for_batch() -> dict:
    """Apply the settings of the module docstring to this process; returns what was set
    (``{"mmap_threshold": bytes, "trim_threshold": bytes, "numpy_hugepage": False}``, each key only
    where it was applied). ``UserError`` for a ``USDGS_ALLOCATOR`` other than ``batch`` or ``default``."""
    done: dict = {}
    choice = os.environ.get(ENV, "").strip().lower()
    if choice not in ("", "batch", "default"):
        raise UserError(f"{ENV}={os.environ[ENV]!r}: use 'batch' (the default: freed buffers kept, no huge-page "
                        "advice) or 'default' (glibc's and numpy's own settings)")
    if choice == "default":
        return done
    libc = _libc()
    if libc is not None:
        for env, param, value, key in (("MALLOC_MMAP_THRESHOLD_", M_MMAP_THRESHOLD, MMAP_THRESHOLD, "mmap_threshold"),
                                       ("MALLOC_TRIM_THRESHOLD_", M_TRIM_THRESHOLD, TRIM_THRESHOLD, "trim_threshold")):
            if env not in os.environ and libc.mallopt(param, value) == 1:
                done[key] = value
    if "NUMPY_MADVISE_HUGEPAGE" not in os.environ:
        if "numpy" not in sys.modules:  # numpy reads it when imported
            os.environ["NUMPY_MADVISE_HUGEPAGE"] = "0"
            done["numpy_hugepage"] = False
        else:
            import numpy as np

            core = getattr(np, "_core", None) or getattr(np, "core", None)  # (numpy 2; 1.26)
            setter = getattr(getattr(core, "multiarray", None), "_set_madvise_hugepage", None)
            if setter is not None:
                setter(False)
                done["numpy_hugepage"] = False
    return done
