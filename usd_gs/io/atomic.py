"""Atomic file output: write to a temporary file beside the target, then rename.

An interrupted or failed write (exception, Ctrl-C) leaves no partial file and leaves an
existing target intact. The finished file gets the usual permissions (0666 minus the
process umask), not the 0600 of ``tempfile.mkstemp``.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_output(target, durable: bool = False) -> Iterator[Path]:
    """Yield a temporary path in ``target``'s directory; on success rename it onto ``target``.

    The temporary name keeps ``target``'s suffix (USD picks the file format from it).
    ``durable`` fsyncs the file before the rename (survives power loss; slower).
    """
    target = Path(target)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=".tmp" + target.suffix, dir=target.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        if durable:
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
