"""Files in and out: stress grids, multichannel EXR, PNG previews."""
from __future__ import annotations

from pathlib import Path

# What a stress export writes, by the output's suffix (any case).
EXPORT_FORMATS = {".vtu": "VTK unstructured grid for ParaView", ".tsv": "3D-TSV stress file"}


def export_format(output: str | Path) -> str:
    """The lower-case suffix of an export's ``output`` (a key of ``EXPORT_FORMATS``); any other is refused."""
    kind = Path(output).suffix.lower()
    if kind not in EXPORT_FORMATS:
        raise ValueError(f"{output}: unknown export format '{Path(output).suffix}'; give a name ending in "
                         + " or ".join(f"{suffix} ({what})" for suffix, what in EXPORT_FORMATS.items()))
    return kind
