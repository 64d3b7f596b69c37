"""PNG previews of single channels."""
from __future__ import annotations

from pathlib import Path

from typing import TYPE_CHECKING

import numpy as np

from .atomic import atomic_path

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from .tsv import BoundaryConditions


def write_preview(path: str | Path, image: np.ndarray, vmin: float = 0.0, vmax: float = 1.0) -> None:
    """Grey-level PNG of an intensity image, linear between ``vmin`` and ``vmax``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    with atomic_path(path, ".png") as tmp:
        plt.imsave(tmp, np.clip(np.asarray(image, dtype=np.float32), vmin, vmax), cmap="gray", vmin=vmin, vmax=vmax,
                   format="png")


def write_colour_preview(path: str | Path, rgb: np.ndarray) -> None:
    """A colour PNG of an ``(H, W, 3)`` image already in display values (sRGB in [0, 1])."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    with atomic_path(path, ".png") as tmp:
        plt.imsave(tmp, np.clip(np.asarray(rgb, dtype=np.float32), 0.0, 1.0), format="png")


def write_comparison(path: str | Path, panels: list[tuple[str, np.ndarray]], title: str,
                     panel_inches: float = 3.6) -> None:
    """Labelled grey-level panels (intensities, 0 to 1) side by side and their difference (first minus second)
    on a signed scale with a colour bar, each panel at least ``panel_inches`` wide whatever the image size."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    (first_label, first), (second_label, second) = panels
    difference = np.asarray(first, np.float64) - np.asarray(second, np.float64)
    bound = max(float(np.abs(difference).max()), 1e-6)
    figure, axes = plt.subplots(1, 3, figsize=(3 * panel_inches + 1.0, panel_inches + 0.8), constrained_layout=True)
    for axis, (label, image) in zip(axes, panels):
        drawn = axis.imshow(np.clip(image, 0, 1), cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        axis.set_title(label)
    figure.colorbar(drawn, ax=axes[:2], shrink=0.8, label="intensity (normalised)")
    shown = axes[2].imshow(difference, cmap="RdBu_r", vmin=-bound, vmax=bound, interpolation="nearest")
    axes[2].set_title(f"{first_label} - {second_label}")
    figure.colorbar(shown, ax=axes[2], shrink=0.8, label="difference")
    for axis in axes:
        axis.set_xlabel("pixel")
    axes[0].set_ylabel("pixel")
    figure.suptitle(title)
    with atomic_path(path, ".png") as tmp:
        figure.savefig(tmp, format="png", dpi=100)
    plt.close(figure)


def mesh_preview_figure(nodes: np.ndarray, surface: np.ndarray, stress: np.ndarray,
                        boundary: BoundaryConditions | None = None, title: str = "") -> Figure:
    """A 3D view of a mesh's boundary surface coloured by von Mises stress, with its boundary conditions.

    ``boundary`` (:class:`~mi_nest.io.tsv.BoundaryConditions`, optional) adds the
    node forces as arrows (length proportional to the force, the largest a
    tenth of the mesh's diagonal, pointing where the force pushes) and the fixed
    nodes as black markers. Returns the matplotlib figure.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from ..physics.tensors import von_mises
    nodes = np.asarray(nodes, dtype=np.float64)
    stress_on_faces = von_mises(np.asarray(stress, dtype=np.float64))[surface].mean(axis=1)
    figure = plt.figure(figsize=(7, 6), dpi=100)
    axis = figure.add_subplot(projection="3d")
    faces = Poly3DCollection(nodes[surface], cmap="viridis", linewidths=0, alpha=0.6)
    faces.set_array(stress_on_faces)
    # Loads and supports are singular: clip the colours at the 99th percentile so the rest of the field shows.
    faces.set_clim(0.0, np.percentile(stress_on_faces, 99))
    axis.add_collection3d(faces)
    figure.colorbar(faces, ax=axis, shrink=0.7, extend="max", label="von Mises stress (MPa)")
    low, high = nodes.min(axis=0), nodes.max(axis=0)
    diagonal = float(np.linalg.norm(high - low))
    if boundary is not None and len(boundary.forces):
        scale = 0.1 * diagonal / max(float(np.linalg.norm(boundary.forces, axis=1).max()), np.finfo(float).tiny)
        tips = nodes[boundary.force_nodes]
        arrows = boundary.forces * scale
        # Arrows end at their node, like a load drawn on a part: the force pushes from tail to tip.
        axis.quiver(*(tips - arrows).T, *arrows.T, color="red", linewidth=1.2, arrow_length_ratio=0.3,
                    label=f"node forces ({len(arrows)})")
    if boundary is not None and len(boundary.fixed_nodes):
        axis.scatter(*nodes[boundary.fixed_nodes].T, color="black", marker="^", s=12, depthshade=False,
                     label=f"fixed nodes ({len(boundary.fixed_nodes)})")
    if boundary is not None and (len(boundary.forces) or len(boundary.fixed_nodes)):
        axis.legend(loc="upper left", fontsize=8)
    centre, half = 0.5 * (low + high), 0.5 * (high - low).max() * 1.1
    axis.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half),
             zlim=(centre[2] - half, centre[2] + half), xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm)")
    axis.set_box_aspect((1, 1, 1))
    axis.set_title(title, fontsize=9)
    return figure


def write_mesh_preview(path: str | Path, nodes: np.ndarray, surface: np.ndarray, stress: np.ndarray,
                       boundary: BoundaryConditions | None = None, title: str = "") -> None:
    """Write :func:`mesh_preview_figure` as a PNG (atomically)."""
    import matplotlib.pyplot as plt

    figure = mesh_preview_figure(nodes, surface, stress, boundary, title)
    with atomic_path(path, ".png") as tmp:
        figure.savefig(tmp, format="png")
    plt.close(figure)
