"""Multichannel EXR files addressed by channel name (OpenEXR does not keep channel order)."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import OpenEXR

from .atomic import atomic_path


class ExrFileError(ValueError):
    """An EXR file is missing, unreadable or lacks a requested channel."""


def write_channels(path: str | Path, channels: dict[str, np.ndarray], metadata: dict | None = None,
                   half: bool = False) -> None:
    """Write ``{name: (H, W) array}`` as one EXR, atomically (temp file + rename).

    ``metadata`` values are stored as string header attributes.
    """
    path = Path(path)
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
            exr.write(tmp)


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
