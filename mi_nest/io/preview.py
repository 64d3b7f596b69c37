"""PNG previews of single channels."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def write_preview(path, image, vmin=0.0, vmax=1.0):
    """Grey-level PNG of an intensity image, linear between ``vmin`` and ``vmax``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    plt.imsave(path, np.clip(np.asarray(image, dtype=np.float32), vmin, vmax), cmap="gray",
               vmin=vmin, vmax=vmax)
