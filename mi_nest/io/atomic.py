"""Write files so that readers never see half of one, and clean up after writers that were killed."""
from __future__ import annotations

import glob
import os
import re
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

# Temporary files are named ``.<target>.mi_nest-tmp<pid>-<random><suffix>`` beside their target: the PID
# tells a killed writer's leftovers (its process is gone) from a running writer's file.
TEMPORARY_MARK = ".mi_nest-tmp"
_WRITER = re.compile(re.escape(TEMPORARY_MARK) + r"(\d+)-")


@contextmanager
def atomic_path(path: str | Path, suffix: str = "") -> Iterator[str]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on failure it is removed.

    The file gets the permissions of a normally created file (``mkstemp`` makes
    it private to the owner). Temporaries of ``path`` left by a writer that was
    killed (no ``finally`` ran) are removed first.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path)
    fd, tmp = tempfile.mkstemp(suffix=suffix, prefix=f".{path.name}{TEMPORARY_MARK}{os.getpid()}-",
                               dir=path.parent)
    os.close(fd)
    try:
        yield tmp
        _flush_to_disk(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _flush_to_disk(path: str) -> None:
    """Make the file's data durable before the rename that publishes it: without this a power cut can
    leave the renamed file cut short, which a resumed run would take for a finished one."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def remove_stale_temporaries(path: str | Path) -> list[Path]:
    """Remove the temporary files of ``path`` whose writing process no longer runs; return their paths."""
    path = Path(path)
    removed = []
    for candidate in path.parent.glob(f".{glob.escape(path.name)}{TEMPORARY_MARK}*"):
        writer = _WRITER.match(candidate.name[len(path.name) + 1:])
        if writer is not None and not _running(int(writer.group(1))):
            candidate.unlink(missing_ok=True)
            removed.append(candidate)
    return removed


def _running(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:     # another user's process
        return True
    return True
