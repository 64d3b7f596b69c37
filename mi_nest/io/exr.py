"""Multichannel EXR files addressed by channel name (OpenEXR does not keep channel order)."""
from __future__ import annotations

import errno
import os
import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import OpenEXR

from .atomic import OUT_OF_ROOM, atomic_path


class ExrFileError(ValueError):
    """An EXR file is missing, unreadable or lacks a requested channel."""


def require_exr_name(path: str | Path) -> Path:
    """``path`` if its name ends in .exr: EXR bytes under another suffix would be taken for what it says."""
    path = Path(path)
    if path.suffix.lower() != ".exr":
        raise ExrFileError(f"{path}: the image is written as OpenEXR, so its name must end in .exr (a PNG "
                           "preview goes to --png NAME.png)")
    return path


def write_channels(path: str | Path, channels: dict[str, np.ndarray], metadata: dict | None = None,
                   half: bool = False) -> None:
    """Write ``{name: (H, W) array}`` as one EXR, atomically (temp file + rename).

    ``metadata`` values are stored as string header attributes.
    """
    path = require_exr_name(path)
    if not channels:
        raise ExrFileError(f"{path}: no channels to write")
    shapes = {np.shape(a) for a in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ExrFileError(f"{path}: channels must share one (H, W) shape, got {sorted(shapes)}")
    dtype = np.float16 if half else np.float32
    pixels = {name: np.ascontiguousarray(a, dtype=dtype) for name, a in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update({key: str(value) for key, value in (metadata or {}).items()})
    with atomic_path(path, ".exr") as tmp:
        with OpenEXR.File(header, pixels) as exr:
            try:
                exr.write(tmp)
            except RuntimeError as error:
                raise _write_error(path, error) from error
        _require_readable(tmp, path)


def _require_readable(tmp, path):
    """Read the temporary file ``tmp`` of ``path`` back whole: OpenEXR does not report the loss of what it writes
    as it closes the file (a small file on a full disk is left empty without a word)."""
    try:
        with OpenEXR.File(str(tmp), separate_channels=True):
            pass
    except Exception as error:  # OpenEXR raises bare RuntimeError/IOError on corrupt files
        if shutil.disk_usage(Path(tmp).parent).free == 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)) from error
        raise ExrFileError(f"{path}: the file written does not read back ({error})") from error


def _write_error(path, error):
    """What OpenEXR's RuntimeError for a failed write stands for: the ``OSError`` of a write that ran out of
    room, whose reason it quotes (``atomic_path`` names the file and the limit), or an ``ExrFileError``."""
    for code in OUT_OF_ROOM:
        if os.strerror(code) in str(error):
            return OSError(code, os.strerror(code))
    return ExrFileError(f"{path}: cannot be written ({error})")


def read_metadata(path: str | Path) -> dict[str, str]:
    """The header attributes ``write_channels`` stored (as strings), by name."""
    path = Path(path)
    try:
        with OpenEXR.File(str(path), header_only=True) as exr:
            # Copied inside: closing the file empties the dictionary it returned.
            header = {key: value for key, value in exr.header().items() if isinstance(value, str)}
    except Exception as error:  # OpenEXR raises bare RuntimeError/IOError on corrupt files
        raise ExrFileError(f"{path}: not a readable EXR file ({error})") from error
    return header


def read_channels(path: str | Path, names: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """Read channels by name as float32 ``(H, W)`` arrays; all of them when ``names`` is None."""
    path = Path(path)
    if not path.is_file():
        raise ExrFileError(f"EXR file not found: {path}")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            available = {name: channel.pixels for name, channel in exr.channels().items()}
    except Exception as error:  # OpenEXR raises bare RuntimeError/IOError on corrupt files
        raise ExrFileError(f"{path}: not a readable EXR file ({error})") from error
    if names is None:
        names = sorted(available)
    missing = [name for name in names if name not in available]
    if missing:
        raise ExrFileError(f"{path}: no channel(s) {missing}; available: {sorted(available)}")
    return {name: np.asarray(available[name], dtype=np.float32) for name in names}
