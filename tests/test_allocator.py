"""usd_gs.pipeline.allocator: freed large buffers are reused without faulting their pages in again,
and what the user set in the environment is left alone. Each case runs in a fresh interpreter
(the settings are process-wide)."""

from __future__ import annotations

import ctypes
import json
import os
import subprocess
import sys

import pytest

from usd_gs.pipeline.allocator import MMAP_THRESHOLD, TRIM_THRESHOLD

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="numpy advises huge pages on Linux only")


def _is_glibc() -> bool:
    try:
        ctypes.CDLL("libc.so.6").gnu_get_libc_version  # noqa: B018
    except (OSError, AttributeError):
        return False
    return True


# allocate, touch and free a 64 MiB buffer 8 times; the minor page faults of the last 7 rounds
_FAULTS = """
import json, resource, sys
from usd_gs.pipeline.allocator import tune_for_batch
done = tune_for_batch()
import numpy as np
faults = []
for _ in range(8):
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a = np.empty(64 << 20, np.uint8)
    a[::4096] = 1
    del a
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
hugepage = bool((getattr(np, "_core", None) or np.core).multiarray._get_madvise_hugepage())
print(json.dumps({"done": done, "repeat_faults": sum(faults[1:]), "hugepage": hugepage}))
"""


_SETTINGS = ("USDGS_ALLOCATOR", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "NUMPY_MADVISE_HUGEPAGE")


def _run(env_extra: dict) -> dict:
    """What ``_FAULTS`` prints in a fresh interpreter with none of ``_SETTINGS`` but ``env_extra``."""
    env = {k: v for k, v in os.environ.items() if k not in _SETTINGS}
    env.update(env_extra)
    out = subprocess.run([sys.executable, "-c", _FAULTS], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux") or not _is_glibc(), reason="glibc's mallopt (Linux)")
def test_freed_buffers_are_reused_without_faulting_again():
    tuned = _run({})
    assert tuned["done"] == {"mmap_threshold": MMAP_THRESHOLD, "trim_threshold": TRIM_THRESHOLD,
                             "numpy_hugepage": False}
    assert tuned["hugepage"] is False
    # 64 MiB of 4 KiB pages is 16,384 faults per round: the tuned rounds after the first fault almost none
    assert tuned["repeat_faults"] < 200
    # glibc's defaults (plain pages, so the faults are countable): every round faults its pages in again
    plain = _run({"USDGS_ALLOCATOR": "default", "NUMPY_MADVISE_HUGEPAGE": "0"})
    assert plain["done"] == {}
    assert plain["repeat_faults"] > 7 * 16384 * 0.9


def test_user_settings_are_left_alone():
    got = _run({"NUMPY_MADVISE_HUGEPAGE": "1", "MALLOC_MMAP_THRESHOLD_": str(1 << 20),
                "MALLOC_TRIM_THRESHOLD_": str(1 << 20)})
    assert got["done"] == {}
    assert got["hugepage"] is True


def test_default_turns_everything_off():
    got = _run({"USDGS_ALLOCATOR": "Default"})
    assert got["done"] == {}
    assert got["hugepage"] is True  # numpy's own default on Linux kernels >= 4.6


def test_an_unknown_choice_is_a_user_error_naming_it(monkeypatch):
    from usd_gs.errors import UserError
    from usd_gs.pipeline.allocator import tune_for_batch

    monkeypatch.setenv("USDGS_ALLOCATOR", "fast")
    with pytest.raises(UserError, match="USDGS_ALLOCATOR='fast': use 'batch'"):
        tune_for_batch()


def test_the_console_script_exits_2_on_an_unknown_choice(tmp_path):
    env = dict(os.environ, USDGS_ALLOCATOR="fast")
    r = subprocess.run([sys.executable, "-m", "usd_gs.cli", "process", str(tmp_path / "none.usda")], env=env,
                       capture_output=True, text=True)
    assert r.returncode == 2 and "USDGS_ALLOCATOR='fast'" in r.stderr
