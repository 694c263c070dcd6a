"""Who writes what: an exclusive lock per cache key, and temporary folders named by their writer.

:func:`key_lock` holds an ``fcntl`` lock on a file beside the entry, so identical runs in flight
compute once. A temporary folder's name (:func:`tmp_name`) carries its writer's host, pid and start
time, so a cleanup can tell a write in progress from an abandoned one (:func:`pid_alive`).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import secrets
import socket
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

__all__ = ["TMP_PREFIX", "host_tag", "key_lock", "parse_tmp", "pid_alive", "proc_stat", "tmp_name"]

TMP_PREFIX = ".tmp-"


# --------------------------------------------------------------------------- temporary folders' writers


def host_tag() -> str:
    """8 hex digits naming this host in a temporary folder's name."""
    return hashlib.sha256(socket.gethostname().encode()).hexdigest()[:8]


def proc_stat(pid: int) -> tuple[str, int] | None:
    """(state, start ticks) of a Linux process from /proc, or None if unavailable."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rfind(")") + 2 :].split()
    return fields[0], int(fields[19])


def pid_alive(pid: int, start: int) -> bool:
    """True if process ``pid`` (started at ``start`` ticks, 0 = unknown) still runs."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    except OSError:
        return False
    st = proc_stat(pid)
    if st is None:
        return True
    state, started = st
    return state not in ("Z", "X") and (start == 0 or started == start)


def tmp_name(key: str) -> str:
    """A fresh temporary folder name for entry ``key``: ``.tmp-KEY-HOST-PID-START-RAND``."""
    st = proc_stat(os.getpid())
    start = st[1] if st else 0
    return f"{TMP_PREFIX}{key}-{host_tag()}-{os.getpid()}-{start}-{secrets.token_hex(4)}"


def parse_tmp(name: str) -> tuple[str, str, int, int] | None:
    """(key, host tag, pid, start) from a temporary folder name, or None."""
    parts = name[len(TMP_PREFIX) :].rsplit("-", 4)
    if not name.startswith(TMP_PREFIX) or len(parts) != 5:
        return None
    key, host, pid, start, _ = parts
    if not (pid.isdigit() and start.isdigit()):
        return None
    return key, host, int(pid), int(start)


# --------------------------------------------------------------------------- a lock per key

_held = threading.local()  # the lock files this thread holds -> depth (a nested take of the same key)


@contextlib.contextmanager
def key_lock(path: Path, on_wait: Callable[[], None] | None = None) -> Iterator[None]:
    """Hold an exclusive ``fcntl.flock`` on the file ``path`` (created if need be, removed on
    release) for the ``with`` block; ``on_wait()`` is called once if another process holds it.

    Re-entrant within a thread. The file is unlinked while still locked, so a waiter that opened the
    old file finds it gone after it gets the lock and locks the new one instead (no two holders)."""
    held: dict[Path, int] = _held.__dict__.setdefault("paths", {})
    if path in held:
        held[path] += 1
        try:
            yield
        finally:
            held[path] -= 1
        return
    fd = _lock_file(path, on_wait)
    if fd is None:   # a file system without locks: the atomic rename still keeps one entry
        yield
        return
    held[path] = 1
    try:
        yield
    finally:
        del held[path]
        with contextlib.suppress(OSError):
            os.unlink(path)
        os.close(fd)


def _lock_file(path: Path, on_wait: Callable[[], None] | None) -> int | None:
    """An open descriptor of ``path`` with its exclusive lock taken (waiting for it if need be); None
    where the file system has no locks (then identical calls in flight may both compute)."""
    told = False
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                if on_wait is not None and not told:
                    on_wait()
                    told = True
                fcntl.flock(fd, fcntl.LOCK_EX)
            mine, now = os.fstat(fd), os.stat(path)
            if (mine.st_ino, mine.st_dev) == (now.st_ino, now.st_dev):
                return fd
        except FileNotFoundError:
            pass   # the holder removed it on release: lock the next one
        except OSError as e:
            if e.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS):
                os.close(fd)
                raise
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(path)
            return None
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)
