"""Principal stresses on a slice plane: sigma_1 >= sigma_2 >= sigma_3, von Mises, and their directions, for a
true field or a reconstruction, and the reconstruction's error against the truth where one is known.

A reconstruction's field is trace-free: photoelasticity does not see the mean stress, so its principal
stresses are the deviator's, ``s_k = sigma_k - (sigma_1 + sigma_2 + sigma_3) / 3``, and it is compared with the
truth's deviator (von Mises and the directions do not depend on the mean stress).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mitsuba as mi
import numpy as np
from scipy.stats import spearmanr

from .. import occupancy
from ..fields.base import sample
from ..physics.tensors import principal_axes, von_mises
from ..physics.tensors import deviatoric_part, tensor_norm
from ..reconstruct.trust import TrustMap
from ..scene import specimen_shapes
from .plots import pyplot, save_figure
from .slicing import Plane, SliceError, SliceImage, slice_image
from .source import ViewSource

QUANTITIES = ("sigma_1", "sigma_2", "sigma_3", "von_mises")
# A full tensor's figure also shows its mean stress (a deviator's is zero).
MEAN = "mean"
# Direction glyphs drawn along the image's longer side.
GLYPHS_ACROSS = 18


@dataclass
class PrincipalSlice:
    """On a plane's pixels: ``stress`` (H, W, 6) in MPa, ``values`` (H, W, 3) largest first, ``directions``
    (H, W, 3, 3) with ``directions[..., k, :]`` along ``values[..., k]``, ``von_mises`` (H, W), ``inside`` (H, W);
    NaN outside."""
    image: SliceImage
    stress: np.ndarray
    values: np.ndarray
    directions: np.ndarray
    von_mises: np.ndarray
    inside: np.ndarray
    deviatoric: bool

    @property
    def quantities(self) -> tuple[str, ...]:
        """What the slice's figure shows: the principal stresses and von Mises, and a full tensor's mean stress."""
        return QUANTITIES if self.deviatoric else QUANTITIES + (MEAN,)

    def quantity(self, name: str) -> np.ndarray:
        if name == "von_mises":
            return self.von_mises
        if name == MEAN:
            return self.stress[..., :3].mean(axis=-1)
        return self.values[..., QUANTITIES.index(name)]

    def in_plane(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The direction of ``values[..., k]`` projected onto the image axes (right, up)."""
        d = self.directions[..., k, :]
        return d @ self.image.right, d @ self.image.up

    def minus(self, truth: PrincipalSlice) -> dict[str, np.ndarray]:
        """Each quantity of this slice minus ``truth``'s."""
        return {name: self.quantity(name) - truth.quantity(name) for name in self.quantities}


def principal_slice(scene: mi.Scene, plane: Plane, resolution: int = 128, field: object | None = None,
                    deviatoric: bool = False) -> PrincipalSlice:
    """The principal stresses of ``scene``'s specimens (or of ``field`` in them) at ``plane``'s pixels inside
    a specimen; ``deviatoric`` takes the mean stress out first."""
    image = slice_image(scene, plane, resolution)
    points = image.centres()
    stress = np.full((len(points), 6), np.nan)
    inside = np.zeros(len(points), dtype=bool)
    for shape in specimen_shapes(scene):
        here = occupancy.inside(scene, [shape], points) & ~inside
        if here.any():
            source = field if field is not None else shape.interior_medium().field
            stress[here] = sample(source, points[here])
        inside |= here
    if not inside.any():
        raise SliceError(f"the plane {plane.describe()} misses the part: no pixel lies inside a specimen")
    if deviatoric:
        mean = stress[:, :3].mean(axis=1, keepdims=True)
        stress[:, :3] -= mean
    values = np.full((len(points), 3), np.nan)
    directions = np.full((len(points), 3, 3), np.nan)
    values[inside], directions[inside] = principal_axes(stress[inside])
    shape = (image.height, image.width)
    mises = np.where(inside, von_mises(np.nan_to_num(stress)), np.nan)
    return PrincipalSlice(image, stress.reshape(*shape, 6), values.reshape(*shape, 3),
                          directions.reshape(*shape, 3, 3), mises.reshape(shape),
                          inside.reshape(shape), deviatoric)


def source_slices(source: ViewSource, plane: Plane, resolution: int = 128
                  ) -> tuple[PrincipalSlice, PrincipalSlice | None]:
    """The slice of ``source`` and, for a reconstruction of simulated data or a separation, of its truth (both
    deviatoric for a reconstruction, full for a separation)."""
    shown = principal_slice(source.scene, plane, resolution, source.field, deviatoric=source.deviatoric)
    truth = source.truth()
    if truth is None:
        return shown, None
    return shown, principal_slice(truth.scene, plane, resolution, None, deviatoric=shown.deviatoric)


def uncertainty_on(shown: PrincipalSlice, trust: TrustMap) -> np.ndarray:
    """A reconstruction's trust-map uncertainty at the slice's pixels inside the part (H, W); NaN outside."""
    values = trust.at(shown.image.centres()).reshape(shown.inside.shape)
    return np.where(shown.inside, values, np.nan)


def deviatoric_error(shown: PrincipalSlice, truth: PrincipalSlice) -> np.ndarray:
    """``|s - s_true|`` (Frobenius, MPa) at each pixel (H, W); NaN where either is outside."""
    return tensor_norm(deviatoric_part(shown.stress) - deviatoric_part(truth.stress))


def uncertainty_ranking(uncertainty: np.ndarray, error: np.ndarray) -> float:
    """The Spearman rank correlation of the uncertainty with the actual error over the pixels where both are
    known: how well the trust map ranks this plane's error (1: in the same order)."""
    both = np.isfinite(uncertainty) & np.isfinite(error)
    if both.sum() < 3:
        return float("nan")
    return float(spearmanr(uncertainty[both], error[both]).statistic)


def write_principal_figure(path: str | Path, shown: PrincipalSlice, truth: PrincipalSlice | None,
                           title: str, uncertainty: np.ndarray | None = None) -> Path:
    """sigma_1, sigma_2, sigma_3 and von Mises (and a full tensor's mean stress) with colour bars in MPa, direction
    glyphs on the principal stresses (their in-plane part: a short glyph points out of the plane); with ``truth``,
    its row and the error row below. A reconstruction's ``uncertainty`` on the plane (:func:`uncertainty_on`) adds a
    column: where to trust it, above the actual deviatoric error when the truth is known."""
    plt = pyplot()
    compared = ("reconstruction" if shown.deviatoric else "separated") if truth is not None else ""
    rows = [(compared, shown)]
    if truth is not None:
        rows.append(("truth", truth))
    row_count = len(rows) + (truth is not None)        # with a truth, its row and the error row
    quantities = shown.quantities
    columns = len(quantities) + (uncertainty is not None)
    figure, axes = plt.subplots(row_count, columns, figsize=(4.25 * columns, 4.2 * row_count), squeeze=False,
                                constrained_layout=True)
    prefix = "s" if shown.deviatoric else "sigma"
    names = {"sigma_1": f"{prefix}_1", "sigma_2": f"{prefix}_2", "sigma_3": f"{prefix}_3", "von_mises": "von Mises",
             MEAN: "mean stress p"}
    # One colour scale per quantity across the rows, so that truth and reconstruction compare by eye.
    limits = {name: _limits([s.quantity(name) for _, s in rows], name) for name in quantities}
    # A principal stress that is zero everywhere (sigma_2 in plane stress) gets the others' scale, not its noise's.
    largest = max(limits[name][1] for name in QUANTITIES[:3])
    for name in QUANTITIES[:3]:
        bound = max(limits[name][1], 0.01 * largest)
        limits[name] = (-bound, bound, limits[name][2])
    extent = shown.image.extent()
    for row, (label, data) in enumerate(rows):
        for column, name in enumerate(quantities):
            axis = axes[row, column]
            low, high, cmap = limits[name]
            values = data.quantity(name)
            drawn = axis.imshow(np.ma.masked_invalid(values), cmap=cmap, vmin=low, vmax=high,
                                extent=extent, interpolation="nearest")
            _colour_bar(figure, axis, drawn, values, low, high, f"{names[name]} (MPa)")
            if column < 3:
                _glyphs(axis, data, column)
            axis.set_title(f"{label} {names[name]}".strip())
            axis.set_xlabel("image right (mm)")
            axis.set_ylabel("image up (mm)")
    if truth is not None:
        errors = shown.minus(truth)
        for column, name in enumerate(quantities):
            axis = axes[-1, column]
            bound = _symmetric_bound(errors[name])
            drawn = axis.imshow(np.ma.masked_invalid(errors[name]), cmap="RdBu_r", vmin=-bound, vmax=bound,
                                extent=extent, interpolation="nearest")
            _colour_bar(figure, axis, drawn, errors[name], -bound, bound, f"error of {names[name]} (MPa)")
            axis.set_title(f"{compared} - truth: {names[name]}")
            axis.set_xlabel("image right (mm)")
            axis.set_ylabel("image up (mm)")
    if uncertainty is not None:
        _trust_column(figure, axes[:, -1], shown, truth, uncertainty)
    return save_figure(figure, path, title, dpi=90)


def _trust_column(figure, column, shown, truth, uncertainty):
    """The uncertainty above (with a truth) the truth row left empty and the actual error it should rank."""
    extent = shown.image.extent()
    panels = [(column[0], uncertainty, "viridis", "stress scales / box length",
               "uncertainty (trust.npz)")]
    if truth is not None:
        column[1].axis("off")
        error = deviatoric_error(shown, truth)
        rho = uncertainty_ranking(uncertainty, error)
        panels.append((column[-1], error, "magma", "|s - s_true| (MPa)", f"actual error (Spearman {rho:.2f})"))
    for axis, values, cmap, label, heading in panels:
        finite = values[np.isfinite(values)]
        high = max(float(np.percentile(finite, 99)), 1e-12) if finite.size else 1.0
        drawn = axis.imshow(np.ma.masked_invalid(values), cmap=cmap, vmin=0.0, vmax=high, extent=extent,
                            interpolation="nearest")
        clipped = finite.size and finite.max() > high
        figure.colorbar(drawn, ax=axis, shrink=0.85, label=label, extend="max" if clipped else "neither")
        axis.set_title(heading)
        axis.set_xlabel("image right (mm)")
        axis.set_ylabel("image up (mm)")


def _colour_bar(figure, axis, drawn, values, low, high, label):
    """A colour bar whose pointed ends say that values lie beyond it (singular loads), with their range."""
    finite = np.asarray(values)[np.isfinite(values)]
    below, above = finite.size and finite.min() < low, finite.size and finite.max() > high
    extend = {(False, False): "neither", (True, False): "min", (False, True): "max", (True, True): "both"}
    if below or above:
        label = f"{label}; beyond the ends: {finite.min():.3g} to {finite.max():.3g}"
    figure.colorbar(drawn, ax=axis, shrink=0.85, label=label, extend=extend[bool(below), bool(above)])


def _limits(images, name):
    values = np.concatenate([np.asarray(image)[np.isfinite(image)] for image in images])
    if name == "von_mises":
        return 0.0, max(float(np.percentile(values, 99)), 1e-9), "magma"
    bound = _symmetric_bound(values)
    return -bound, bound, "RdBu_r"


def _symmetric_bound(values):
    """The 99th percentile of |values|: point loads are singular, the colours are for the rest."""
    finite = np.abs(np.asarray(values)[np.isfinite(values)])
    return max(float(np.percentile(finite, 99)), 1e-9) if finite.size else 1.0


def _glyphs(axis, data, k):
    """Headless segments along each principal direction on a coarse grid, scaled by their in-plane part."""
    height, width = data.inside.shape
    every = max(1, max(height, width) // GLYPHS_ACROSS)
    rows, cols = np.mgrid[every // 2:height:every, every // 2:width:every]
    keep = data.inside[rows, cols]
    across, up = (x[rows, cols][keep] for x in data.in_plane(k))
    left, _, _, top = data.image.extent()
    x = left + (cols[keep] + 0.5) * data.image.pixel
    y = top - (rows[keep] + 0.5) * data.image.pixel
    length = 0.8 * every * data.image.pixel
    axis.quiver(x, y, across * length, up * length, angles="xy", scale_units="xy", scale=1, headwidth=0,
                headlength=0, headaxislength=0, pivot="middle", width=0.004, color="black")
