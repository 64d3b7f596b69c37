"""Write files so that readers never see half of one, and clean up after writers that were killed."""
from __future__ import annotations

import errno
import glob
import os
import re
import resource
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

# Temporary files are named ``.<target>.mi_nest-tmp<pid>-<random><suffix>`` beside their target: the PID
# tells a killed writer's leftovers (its process is gone) from a running writer's file.
TEMPORARY_MARK = ".mi_nest-tmp"
_WRITER = re.compile(re.escape(TEMPORARY_MARK) + r"(\d+)-")
# What a write that ran out of room fails with: a full disk, a quota, the file-size limit (ulimit -f).
OUT_OF_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


class OutOfRoomError(OSError):
    """A file could not be written whole for want of room; its message names the file (not the temporary
    it was written as) and the limit."""

    def __init__(self, path: Path, code: int):
        super().__init__(code, os.strerror(code), str(path))
        self.message = f"cannot write {path}: {_room_left(path, code)}"

    def __str__(self) -> str:
        return self.message


def _room_left(path, code):
    if code == errno.EFBIG:
        limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if limit != resource.RLIM_INFINITY:
            return (f"file too large: this process may write files of up to {_size(limit)} (ulimit -f); raise "
                    "the limit or write a smaller file")
        return "file too large for its file system; write it elsewhere or write a smaller file"
    if code == errno.EDQUOT:
        return "disk quota exceeded; free some of your space or write elsewhere"
    return (f"no space left on the device ({_size(shutil.disk_usage(path.parent).free)} free); free some space "
            "or write elsewhere")


def _size(count):
    for unit, scale in (("GiB", 2 ** 30), ("MiB", 2 ** 20), ("KiB", 2 ** 10)):
        if count >= scale:
            return f"{count / scale:.3g} {unit}"
    return f"{count} bytes"


def require_file_path(path: str | Path, option: str | None = None, suffix: str = "") -> Path:
    """``path`` unless it is a directory, which a file cannot replace; ``option`` and ``suffix`` name the
    command-line option and what kind of file it takes."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{f'{option} ' if option else ''}{path} is a directory; give a file to write, such as "
                         f"{path / ('NAME' + suffix)}")
    return path


@contextmanager
def atomic_path(path: str | Path, suffix: str = "") -> Iterator[str]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on failure it is removed.

    The file gets the permissions of a normally created file (``mkstemp`` makes
    it private to the owner). Temporaries of ``path`` left by a writer that was
    killed (no ``finally`` ran) are removed first.
    """
    path = require_file_path(path, suffix=suffix)
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
    except OSError as error:
        if error.errno in OUT_OF_ROOM and not isinstance(error, OutOfRoomError):
            raise OutOfRoomError(path, error.errno) from error
        raise
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def refuse_overwriting_inputs(outputs: Mapping[str, str | Path | None], inputs: Iterable[str | Path]) -> None:
    """Refuse an output that is one of the ``inputs`` (the same file under any name): writing it would destroy
    what the command reads. ``outputs``: the option that names each (None: not given)."""
    existing = [Path(source) for source in inputs if Path(source).is_file()]
    for option, output in outputs.items():
        if output is None or not Path(output).is_file():
            continue
        for source in existing:
            if os.path.samefile(output, source):
                raise ValueError(f"{option} {output} would overwrite {source}, an input of this command; give "
                                 f"{option} another path")


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
