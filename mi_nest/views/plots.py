"""Figures of what lies inside: a slice's fringes with its isochromatic order and isoclinic angle maps; the
interference colours of white light (a Michel-Levy chart)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.atomic import atomic_path
from ..render import RenderResult


def pyplot():
    """matplotlib's pyplot on the Agg backend (no screen here, nor needed)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save_figure(figure, path: str | Path, title: str, dpi: int = 100) -> Path:
    """``figure`` titled, written atomically as a PNG at ``path`` and closed."""
    figure.suptitle(title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, ".png") as tmp:
        figure.savefig(tmp, format="png", dpi=dpi)
    pyplot().close(figure)
    return path


def slice_extent(result: RenderResult) -> tuple[float, ...]:
    """``(left, right, bottom, top)`` in mm of a slice (its EXR metadata)."""
    return tuple(float(x) for x in result.metadata["mi_nest.extent_mm"].split(","))


def write_slice_maps(path: str | Path, result: RenderResult, title: str) -> Path:
    """One PNG: the fringes, the isochromatic order N (colour bar in fringes) and the isoclinic angle (degrees
    from image right to sigma_1), on axes in mm; blank where the slab holds none of the part."""
    plt = pyplot()
    outside = result.channels["slab.mask"] == 0
    extent = slice_extent(result)
    panels = (("fringes", result.channels["Y"], "gray", (0.0, 1.0), "intensity"),
              ("isochromatic order", result.channels["fringe.order"], "viridis", (0.0, None), "fringe order N"),
              ("isoclinic angle", result.channels["isoclinic.angle"], "twilight", (-90.0, 90.0),
               "sigma_1 from image right (degrees)"))
    figure, axes = plt.subplots(1, 3, figsize=(14, 4.6), constrained_layout=True)
    for axis, (name, image, cmap, (low, high), label) in zip(axes, panels):
        shown = np.ma.masked_where(outside, image)
        if high is None:    # point loads are singular: the 99th percentile keeps the colours for the rest
            high = max(float(np.percentile(shown.compressed(), 99)), 1e-6) if shown.count() else 1.0
        drawn = axis.imshow(shown, cmap=cmap, vmin=low, vmax=high, extent=extent, interpolation="nearest")
        axis.set_title(name)
        axis.set_xlabel("image right (mm)")
        axis.set_ylabel("image up (mm)")
        figure.colorbar(drawn, ax=axis, shrink=0.85, label=label)
    return save_figure(figure, path, title)


def write_michel_levy_chart(path: str | Path, light=None, max_retardation: float = 1800.0,
                            reference_wavelength: float = 550.0) -> Path:
    """The interference colours of a retarder between crossed and parallel polarisers in white light (default: a
    white LED, ``physics.colour.white_led``) against its retardation (nm) and its fringe order at
    ``reference_wavelength``: a Michel-Levy chart, the photoelastician's key from colour to fringe order."""
    from ..physics.colour import interference_colours, white_led
    light = white_led() if light is None else light
    retardation = np.linspace(0.0, max_retardation, 900)
    plt = pyplot()
    figure, axes = plt.subplots(2, 1, figsize=(10, 3.2), sharex=True, constrained_layout=True)
    for ax, field in zip(axes, ("dark", "light")):
        strip = interference_colours(retardation, light, field)[None, :, :]
        ax.imshow(np.repeat(strip, 40, axis=0), aspect="auto", extent=(0.0, max_retardation, 0.0, 1.0))
        ax.set_yticks([])
        ax.set_ylabel(f"{field}\nfield", rotation=0, ha="right", va="center")
    axes[-1].set_xlabel("retardation (nm)")
    order = axes[0].secondary_xaxis("top", functions=(lambda r: r / reference_wavelength,
                                                      lambda n: n * reference_wavelength))
    order.set_xlabel(f"fringe order at {reference_wavelength:g} nm")
    return save_figure(figure, path, f"interference colours in {light.name} light (plane polariscope at 45 degrees)")
