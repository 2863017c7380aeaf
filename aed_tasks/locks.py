"""One writer per output folder: an OS lock on `<folder>/.aed.lock`, which names its holder.

Collections, rollouts, trainings and feature caches are written by one run at a time. Two runs
over one folder would plan the same shards, write the same temporary files and delete each
other's leftovers, so the second is refused at once, in one line naming the first one's pid.

The lock is `fcntl.flock` on the lock file: the kernel releases it when its holder dies, even
by `kill -9`, so a lock left by a dead run is taken over (with a warning naming that pid).
Where a filesystem offers no `flock`, the pid written in the file decides alone: a live pid
holds the folder, a dead one is taken over. The holder removes the file when it is done.
"""

from __future__ import annotations

import errno
import fcntl
import functools
import logging
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

logger = logging.getLogger(__name__)
R = TypeVar("R")

LOCK_NAME = ".aed.lock"
_BUSY = (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES)


class FolderLockedError(RuntimeError):
    """Another live process is writing into the folder (the message names its pid)."""


def pid_alive(pid: int) -> bool:
    """Whether a process with this pid exists (a zombie counts: it still holds its pid)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


class FolderLock:
    """The exclusive writer's lock of one folder; `acquire` creates the folder if needed."""

    def __init__(self, folder: Path | str):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self._fd: int | None = None
        self._made: list[Path] = []

    def acquire(self) -> FolderLock:
        """Take the lock, or raise `FolderLockedError` naming the live holder's pid."""
        if self._fd is not None:
            raise RuntimeError(f"{self.folder}: this lock is already held")
        if self.folder.exists() and not self.folder.is_dir():
            raise ValueError(f"{self.folder}: a file, not a folder")
        self._made = [p for p in (self.folder, *self.folder.parents) if not p.exists()]
        self.folder.mkdir(parents=True, exist_ok=True)
        for _ in range(20):  # a holder may remove the file between our open and our lock
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                self._lock(fd)
                if _same_file(fd, self.path):
                    self._take(fd)
                    return self
            except BaseException:
                os.close(fd)
                raise
            os.close(fd)
        raise FolderLockedError(f"{self.folder}: its lock file {LOCK_NAME} keeps being replaced")

    def _lock(self, fd: int) -> None:
        """flock(fd), or the pid's liveness where flock is not supported; refuses a live one."""
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
        except OSError as e:
            if e.errno in _BUSY:
                raise self._busy(_read_pid(fd)) from None
            logger.warning("%s: no flock here (%s); the holder's pid decides alone", self.path, e)
        holder = _read_pid(fd)
        if holder is not None and holder != os.getpid() and pid_alive(holder):
            raise self._busy(holder)

    def _busy(self, holder: int | None) -> FolderLockedError:
        who = f"pid {holder}" if holder is not None else "a process whose pid is not written yet"
        return FolderLockedError(
            f"{self.folder}: another run ({who}) is writing here; wait for it to end, "
            "or write elsewhere"
        )

    def _take(self, fd: int) -> None:
        previous = _read_pid(fd)
        if previous is not None and previous != os.getpid():
            state = "no longer running" if not pid_alive(previous) else "its pid now reused"
            logger.warning(
                "%s: taking over a stale lock left by pid %d (%s)", self.folder, previous, state
            )
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        os.fsync(fd)
        self._fd = fd

    def release(self) -> None:
        """Remove the lock file, then unlock (a waiter that opened it sees it was replaced), then
        the folders `acquire` made if they stayed empty: a refused run leaves nothing behind."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            if _same_file(fd, self.path):
                self.path.unlink()
        finally:
            os.close(fd)  # closing the last descriptor releases the flock
        for folder in self._made:  # deepest first
            try:
                folder.rmdir()
            except OSError:  # not empty (the run wrote there), or already gone
                break

    def __enter__(self) -> FolderLock:
        return self.acquire()

    def __exit__(self, *_: object) -> None:
        self.release()


@contextmanager
def folder_lock(folder: Path | str, wait: bool = False) -> Iterator[FolderLock]:
    """Hold `folder`'s writer lock for the block (see `FolderLock`). `wait`: a held lock is
    waited for (a cache another process is filling) instead of refused."""
    lock, told = FolderLock(folder), False
    while True:
        try:
            lock.acquire()
            break
        except FolderLockedError as e:
            if not wait:
                raise
            if not told:
                logger.info("%s (waiting for it)", e)
                told = True
            time.sleep(0.2)
    try:
        yield lock
    finally:
        lock.release()


def locks_out_folder(fn: Callable[..., R]) -> Callable[..., R]:
    """Decorator: `fn(cfg, ...)` runs holding the lock of `cfg.out` (e.g. a training's folder)."""

    @functools.wraps(fn)
    def locked(cfg: Any, *args: Any, **kwargs: Any) -> R:
        with folder_lock(cfg.out):
            return fn(cfg, *args, **kwargs)

    return locked


def lock_holder(folder: Path | str) -> int | None:
    """The pid written in `folder`'s lock file (None: no lock file, or no pid in it)."""
    try:
        fd = os.open(Path(folder) / LOCK_NAME, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        return _read_pid(fd)
    finally:
        os.close(fd)


def _read_pid(fd: int) -> int | None:
    text = os.pread(fd, 32, 0).decode(errors="replace").strip()
    return int(text) if text.isdigit() else None


def _same_file(fd: int, path: Path) -> bool:
    """Whether `path` still names the file open as `fd` (not removed nor replaced)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    own = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)
