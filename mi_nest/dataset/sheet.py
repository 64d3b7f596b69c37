"""Contact sheet of a dataset: one channel of every rotation, azimuth across, elevation down."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .loader import Dataset


def contact_sheet(dataset: Dataset, channel: str = "pol.45.0.0", gap: int = 2
                  ) -> tuple[np.ndarray, list[float], list[float]]:
    """The tiled ``(rows * (H + gap), columns * (W + gap))`` image (NaN in the gaps and missing tiles)."""
    azimuths = sorted({r["azimuth"] for r in dataset.rotations})
    elevations = sorted({r["elevation"] for r in dataset.rotations})
    width, height = dataset.resolution
    sheet = np.full((len(elevations) * (height + gap) - gap, len(azimuths) * (width + gap) - gap), np.nan,
                    dtype=np.float32)
    for position, rotation in enumerate(dataset.rotations):
        row, column = elevations.index(rotation["elevation"]), azimuths.index(rotation["azimuth"])
        y, x = row * (height + gap), column * (width + gap)
        sheet[y:y + height, x:x + width] = dataset.view(position, [channel])[channel]
    return sheet, azimuths, elevations


def write_contact_sheet(path: str | Path, dataset: Dataset, channel: str = "pol.45.0.0") -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sheet, azimuths, elevations = contact_sheet(dataset, channel)
    aspect = sheet.shape[0] / sheet.shape[1]
    figure, axis = plt.subplots(figsize=(10, 10 * aspect + 0.8), dpi=100)
    axis.imshow(np.ma.masked_invalid(sheet), cmap="gray", vmin=0.0, vmax=1.0, interpolation="nearest")
    axis.set_xticks([(i + 0.5) * sheet.shape[1] / len(azimuths) for i in range(len(azimuths))])
    axis.set_xticklabels([f"{a:g}" for a in azimuths], fontsize=6, rotation=90)
    axis.set_yticks([(i + 0.5) * sheet.shape[0] / len(elevations) for i in range(len(elevations))])
    axis.set_yticklabels([f"{e:g}" for e in elevations], fontsize=6)
    axis.set_xlabel("azimuth (deg)")
    axis.set_ylabel("elevation (deg)")
    axis.set_title(f"{dataset.directory.name}: {channel}, {len(dataset)} rotations", fontsize=9)
    figure.tight_layout()
    from ..io.atomic import atomic_path
    with atomic_path(path, ".png") as tmp:
        figure.savefig(tmp, format="png")
    plt.close(figure)
