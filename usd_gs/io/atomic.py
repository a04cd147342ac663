"""Atomic file output: write to a temporary file beside the target, then rename.

An interrupted or failed write (exception, Ctrl-C, SIGTERM) leaves no partial file and
leaves an existing target intact. The finished file gets the usual permissions (0666 minus
the process umask), not the 0600 of ``tempfile.mkstemp``.

A process killed outright (SIGKILL, power loss) cannot clean up: its temporary files stay.
Their names carry the writer's process id and host (:func:`temp_tag`,
``.<stem>.tmp<pid>-<host>.<random><suffix>``; temp folders ``...tmp<pid>-<host>``), so the next
write into the same folder removes those of processes that no longer run on this host
(:func:`remove_stale_temps`); temporary files of live processes and of other hosts are left.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
import zlib
from collections.abc import Iterator
from pathlib import Path

#: Matches the temporary names this module (and the pipeline's temp folders) make; groups pid, host.
TEMP_NAME = re.compile(r"^\..*\.tmp(?P<pid>\d+)-(?P<host>[0-9a-f]{6})(?:\.[A-Za-z0-9_]+)?(?:\.[^.]+)?$"
                       r"|^\..*_probes\.tmp(?P<pid2>\d+)$")  # the second: probe folders of older versions

def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def host_tag() -> str:
    """Six hex digits naming this host (CRC-32 of the host name)."""
    # os.uname().nodename is what socket.gethostname() returns (importing socket costs ~5 ms)
    if hasattr(os, "uname"):
        name = os.uname().nodename
    else:  # Windows
        import socket

        name = socket.gethostname()
    return f"{zlib.crc32(name.encode()) & 0xFFFFFF:06x}"


def temp_tag() -> str:
    """``tmp<pid>-<host>``: the part of a temporary name that says which process made it."""
    return f"tmp{os.getpid()}-{host_tag()}"


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    except OSError:
        return True
    return True


def remove_stale_temps(folder) -> list[str]:
    """Remove the temporary files and folders in ``folder`` (not recursive) left by killed
    processes of this host (:data:`TEMP_NAME`, pid no longer running). Returns the names
    removed; errors are ignored. Costs one directory listing."""
    folder = os.path.abspath(os.fspath(folder))
    removed = []
    here = host_tag()
    try:
        names = [n for n in os.listdir(folder) if n.startswith(".") and ".tmp" in n]
    except OSError:
        return removed
    for name in names:
        m = TEMP_NAME.match(name)
        if not m:
            continue
        pid, host = (m.group("pid"), m.group("host")) if m.group("pid") else (m.group("pid2"), here)
        if host != here or _alive(int(pid)):
            continue
        path = os.path.join(folder, name)
        with contextlib.suppress(OSError):
            if os.path.isdir(path) and not os.path.islink(path):
                shutil.rmtree(path)
            else:
                os.unlink(path)
            removed.append(name)
    return removed


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM that arrive while the block runs are noted and handed to the handlers
    they would have met once it ends (in the main thread, where Python runs signal handlers;
    elsewhere nothing changes): a Ctrl-C cannot land between creating a file and taking charge
    of it. SIGALRM is held likewise: ``usdgs`` raises a SIGINT or SIGTERM that landed inside a
    module import from its SIGALRM handler once the import is done (``usd_gs.cli``), so that one
    too waits for the block's end. Python handlers are swapped, not the signal mask: any thread
    may receive a signal sent to the process."""
    import signal
    import sys
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    noted: list[int] = []

    def note(signum, frame):
        noted.append(signum)

    previous = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGALRM):
            previous[sig] = signal.signal(sig, note)
    except (ValueError, OSError):  # (an embedding that does not allow it: as before)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        yield
        return
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        for signum in dict.fromkeys(noted):  # (in the order they came, each once, until one raises)
            handler = previous[signum]
            if callable(handler):
                handler(signum, sys._getframe())
            elif handler == signal.SIG_DFL:
                os.kill(os.getpid(), signum)


def check_writable_folder(folder, what: str) -> None:
    """``UserError`` naming ``what`` unless a file can be created in ``folder`` (tries it; an
    interrupt waits until the trial file is gone)."""
    from usd_gs.errors import UserError

    folder = os.path.abspath(os.fspath(folder))
    if not os.path.isdir(folder):
        raise UserError(f"{what}: output directory {folder} does not exist")
    with signals_held():
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".usdgs-check.{temp_tag()}.", dir=folder)
        except OSError as exc:
            raise UserError(f"{what}: cannot write into {folder} ({exc.strerror or exc})") from None
        os.close(fd)
        os.unlink(tmp)


@contextlib.contextmanager
def atomic_output(target, durable: bool = False) -> Iterator[Path]:
    """Yield a temporary path in ``target``'s directory; on success rename it onto ``target``.

    The temporary name keeps ``target``'s suffix (USD picks the file format from it).
    ``durable`` fsyncs the file before the rename (survives power loss; slower). A target that
    is an existing directory, or a folder that cannot be written, raises ``UserError``.
    """
    from usd_gs.errors import UserError

    target = Path(target)
    if target.is_dir():
        raise UserError(f"{target}: is an existing directory, not a file that can be written")
    remove_stale_temps(target.parent)
    tmp = None
    try:
        with signals_held():  # (an interrupt arrives once the cleanup below knows the file)
            try:
                fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.{temp_tag()}.", suffix=target.suffix,
                                           dir=target.parent)
            except FileNotFoundError:
                raise UserError(f"{target}: output directory {target.parent.absolute()} does not exist") from None
            except OSError as exc:
                raise UserError(f"{target}: cannot write into {target.parent.absolute()} ({exc.strerror or exc})") \
                    from None
            os.close(fd)
        yield Path(tmp)
        if durable:
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        try:
            os.replace(tmp, target)
        except IsADirectoryError:
            raise UserError(f"{target}: is an existing directory, not a file that can be written") from None
        except OSError as exc:
            if isinstance(exc, (PermissionError,)):
                raise UserError(f"{target}: cannot be replaced ({exc.strerror or exc})") from None
            raise
    except BaseException:
        if tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        raise
