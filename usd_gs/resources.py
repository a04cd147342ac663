"""Size limits of the user-facing options and a memory estimate checked before a run starts.

Every size a user can ask for has a documented maximum (:data:`LIMITS`): above it the request
is refused as a user error, whatever the machine. Below it, :func:`check_memory` compares a
run's estimated peak working set with the memory the machine has available now
(``MemAvailable`` of ``/proc/meminfo``; unknown elsewhere: no check) and refuses with the
estimate and the option to reduce, instead of running into ``MemoryError`` or the OOM killer.
"""

from __future__ import annotations

from usd_gs.errors import UserError

#: option name -> (minimum, maximum) of the sizes a user may request.
LIMITS = {
    "atlas_size": (8, 16384),  # DGSM octahedral atlas side, pixels
    "K": (1, 1024),  # DGSM depth bins per atlas pixel
    "n_samples": (1, 256),  # Monte Carlo footprint samples per receiver
    "probe_size": (4, 1024),  # probe cube face side, pixels
    "width": (1, 16384),  # render width, pixels
    "eval_width": (16, 8192),  # eval camera width, pixels
}


def check_limit(name: str, value, option: str | None = None) -> int:
    """``value`` as an int when it is an integer within :data:`LIMITS` ``[name]``, else ``UserError``
    naming ``option`` (default ``--<name>``)."""
    lo, hi = LIMITS[name]
    opt = option or "--" + name.replace("_", "-")
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise UserError(f"{opt} must be an integer, got {value!r}")
    if not lo <= value <= hi:
        raise UserError(f"{opt} {value} is out of range: {lo}..{hi}")
    return value


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation now (Linux ``MemAvailable``), or None."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def check_memory(estimate: float, what: str, reduce: str) -> None:
    """``UserError`` when ``estimate`` bytes exceed the available memory: names ``what`` needs it
    and which option to ``reduce``."""
    avail = available_memory()
    if avail is not None and estimate > avail:
        raise UserError(f"{what} needs about {estimate / 2**30:.1f} GiB but {avail / 2**30:.1f} GiB of memory is "
                        f"available; reduce {reduce}")
