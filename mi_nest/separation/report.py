"""A separation against a known truth, and its figure: the mean stress on the part's middle plane."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..fields import StressField
from ..fields.base import sample
from ..io.atomic import atomic_path
from ..physics.tensors import deviatoric_part, tensor_norm
from .solver import Lattice

# "Away from the loaded regions": farther from every loaded surface point than this share of the part's size.
AWAY_SHARE = 0.1


def inside_nodes(separation) -> np.ndarray:
    nz, ny, nx = separation.mean.shape
    lattice = Lattice(separation.grid.bbox_min, separation.grid.bbox_max, (nx, ny, nz))
    return lattice.nodes()[separation.inside.ravel()]


def errors(found: np.ndarray, truth: np.ndarray) -> dict:
    """Relative errors of ``(N, 6)`` full tensors against the truth's: the full tensor's, the deviator's, and the
    mean stress's RMS error per the truth's RMS stress (its stress scale)."""
    scale = float(np.sqrt(np.mean(tensor_norm(truth) ** 2)))
    return {"full": float(np.sqrt(np.mean(tensor_norm(found - truth) ** 2)) / scale),
            "deviatoric": float(np.sqrt(np.mean(tensor_norm(deviatoric_part(found) - deviatoric_part(truth)) ** 2)
                                        / np.mean(tensor_norm(deviatoric_part(truth)) ** 2))),
            "mean_per_scale": float(np.sqrt(np.mean((found[:, :3].mean(1) - truth[:, :3].mean(1)) ** 2)) / scale),
            "points": int(len(found))}


def against_truth(separation, truth: StressField) -> dict:
    """Errors at the lattice's nodes inside the part, all of them and those away from the loaded regions
    (:data:`AWAY_SHARE` of the part's size)."""
    from scipy.spatial import cKDTree
    points = inside_nodes(separation)
    found = separation.field_values(points)
    true = sample(truth, points)
    result = {"all": errors(found, true)}
    if len(separation.loaded_points):
        size = float(np.max(points.max(axis=0) - points.min(axis=0)))
        distance, _ = cKDTree(separation.loaded_points).query(points)
        away = distance > AWAY_SHARE * size
        if away.any():
            result["away_from_loads"] = errors(found[away], true[away])
    return {kind: {k: round(v, 5) if isinstance(v, float) else v for k, v in values.items()}
            for kind, values in result.items()}


def write_figure(path: str | Path, separation, truth: StressField | None, title: str) -> Path:
    """The mean stress on the lattice's middle plane across the part's thinnest side; with ``truth``, the true
    mean stress and the difference beside it."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    nz, ny, nx = separation.mean.shape
    low, high = np.asarray(separation.grid.bbox_min), np.asarray(separation.grid.bbox_max)
    inside = inside_nodes(separation)
    thin = int(np.argmin(inside.max(axis=0) - inside.min(axis=0)))
    middle = 0.5 * (inside.max(axis=0) + inside.min(axis=0))[thin]
    index = int(np.rint((middle - low[thin]) / ((high - low)[thin] / (separation.mean.shape[2 - thin] - 1))))
    take = [slice(None)] * 3
    take[2 - thin] = index
    mean = np.where(separation.inside[tuple(take)], separation.mean[tuple(take)], np.nan)
    shown = [("mean stress p (MPa)", mean)]
    if truth is not None:
        lattice = Lattice(low, high, (nx, ny, nz))
        nodes = lattice.nodes().reshape(nz, ny, nx, 3)[tuple(take)]
        true = sample(truth, nodes.reshape(-1, 3))[:, :3].mean(axis=1).reshape(mean.shape)
        true = np.where(np.isnan(mean), np.nan, true)
        shown += [("true mean stress (MPa)", true), ("separated - true (MPa)", mean - true)]
    axes_left = [a for a in range(3) if a != thin]
    extent = [low[axes_left[0]], high[axes_left[0]], low[axes_left[1]], high[axes_left[1]]]
    figure, axes = plt.subplots(1, len(shown), figsize=(5 * len(shown), 4.4), squeeze=False, constrained_layout=True)
    bound = np.nanmax(np.abs(np.concatenate([v.ravel() for _, v in shown[:2]])))
    for axis, (label, values) in zip(axes[0], shown):
        limit = bound if "-" not in label else max(np.nanmax(np.abs(values)), 1e-12)
        drawn = axis.imshow(np.ma.masked_invalid(values), origin="lower", extent=extent, cmap="RdBu_r",
                            vmin=-limit, vmax=limit)
        axis.set_title(label)
        axis.set_xlabel(f"{'xyz'[axes_left[0]]} (mm)")
        axis.set_ylabel(f"{'xyz'[axes_left[1]]} (mm)")
        figure.colorbar(drawn, ax=axis, shrink=0.85)
    figure.suptitle(f"{title} ({'xyz'[thin]} = {middle:.3g} mm)")
    with atomic_path(path, ".png") as tmp:
        figure.savefig(tmp, dpi=110, format="png")
    plt.close(figure)
    return Path(path)
