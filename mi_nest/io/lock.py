"""One writer per output directory: an OS lock held for the run.

Two runs writing one dataset or result directory mix their files (views of two
noise levels under one ``complete: true``, a journal with every frame twice).
A run holds an exclusive ``flock`` on ``<directory>/.mi_nest.lock`` while it
writes; a second writer is refused at once with the holder's PID and command,
which the holder writes into the file. The OS releases the lock when the
holder's process ends, however it ends, so a crash leaves no stale lock.
"""
from __future__ import annotations

import fcntl
import os
import socket
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

LOCK_FILE = ".mi_nest.lock"

# Directories this process holds: a run may lock a directory that a function it calls locks again (flock
# would refuse the second open file description of one process); the inner block then holds nothing more.
_held = set()


class DirectoryInUseError(OSError):
    """Another run is writing the output directory."""


@contextmanager
def locked_directory(directory: str | Path) -> Iterator[Path]:
    """Hold ``directory`` (created if missing, removed again if left empty) for this process until the block ends.

    Raises :class:`DirectoryInUseError` naming the run that holds it.
    """
    directory = Path(directory)
    created = not directory.exists()
    directory.mkdir(parents=True, exist_ok=True)
    key = str(directory.resolve())
    if key in _held:
        yield directory
        return
    path = directory / LOCK_FILE
    fd = _lock(path, directory)
    _held.add(key)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, (f"PID {os.getpid()} on {socket.gethostname()} since {time.strftime('%Y-%m-%d %H:%M:%S')}: "
                      f"{' '.join(sys.argv)}\n").encode())
        yield directory
    finally:
        _held.discard(key)
        # Unlinked while still locked: a writer that opened the old file sees it is gone and retries.
        path.unlink(missing_ok=True)
        os.close(fd)
        if created:     # a run that wrote nothing leaves nothing; rmdir leaves a directory with files alone
            with suppress(OSError):
                directory.rmdir()


def other_entries(directory: str | Path) -> list[Path]:
    """What ``directory`` holds besides a lock file: whether it is empty for a new run."""
    return [entry for entry in Path(directory).iterdir() if entry.name != LOCK_FILE]


def _lock(path, directory):
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 4096).decode(errors="replace").strip() or "a run that has not said who it is"
            os.close(fd)
            raise DirectoryInUseError(f"{directory} is in use by another run ({holder}); wait for it to end or "
                                      "write to another directory") from None
        try:
            if os.path.samestat(os.fstat(fd), os.stat(path)):
                return fd
        except FileNotFoundError:
            pass
        # The holder before us removed the file between our open and our lock: this lock guards nothing.
        os.close(fd)
