"""How good a reconstruction is: stress errors over the occupied volume, PSNR of held-out views."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import mitsuba as mi
import numpy as np

from .. import occupancy
from ..fields.base import StressField, sample
from ..io.grid import grid_nodes
from ..physics.tensors import deviatoric_part, principal_difference, tensor_norm
from ..scene import specimen_bounds
from .fields import TrainableField, stored_components

if TYPE_CHECKING:
    import scipy.sparse

# Points per axis of the evaluation lattice along the longest side of the specimen.
EVALUATION_POINTS = 40
# A grid floor below this (relative error) from a grid with as many nodes as points: a fit through every point.
FLOOR_OF_A_FIT_THROUGH_EVERY_POINT = 1e-3


@dataclass
class StressErrors:
    deviatoric: float             # ||dev(s) - dev(s_true)|| / ||dev(s_true)|| over the occupied volume
    principal_difference: float   # the same for sigma_max - sigma_min (the 3D principal stress difference)
    points: int

    def describe(self) -> str:
        return (f"deviatoric stress error {100 * self.deviatoric:.1f}%, principal stress difference error "
                f"{100 * self.principal_difference:.1f}% ({self.points} points inside the specimen)")


def evaluation_points(scene: mi.Scene, shapes: list[mi.Shape], points_per_axis: int = EVALUATION_POINTS) -> np.ndarray:
    """A lattice over the specimens' bounding box, cell centres, kept where inside a specimen."""
    low, high = specimen_bounds(shapes)
    spacing = (high - low).max() / points_per_axis
    axes = [np.arange(lo + 0.5 * spacing, hi, spacing) for lo, hi in zip(low, high)]
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return lattice[occupancy.inside(scene, shapes, lattice)]


def stress_errors(field: StressField, truth: StressField, points: np.ndarray) -> StressErrors:
    """Relative errors of ``field`` against ``truth`` at ``points`` (inside the specimen)."""
    probe = ErrorProbe(truth, points)
    estimate = deviatoric_part(sample(field, points))
    true_difference = principal_difference(probe.reference)
    difference = np.linalg.norm(principal_difference(estimate) - true_difference) / np.linalg.norm(true_difference)
    return StressErrors(probe.error_of(estimate), float(difference), len(points))


class ErrorProbe:
    """The deviatoric error of a field against ``truth`` at fixed ``points``, truth sampled once.

    Cheap enough to follow the error during an optimisation (``track_error_every``).
    """

    def __init__(self, truth: StressField, points: np.ndarray):
        if len(points) == 0:
            raise ValueError("no evaluation point lies inside the specimen")
        self.points = points
        self.reference = deviatoric_part(sample(truth, points))
        self.scale = np.sqrt((tensor_norm(self.reference) ** 2).sum())
        if self.scale == 0:
            raise ValueError("the true stress field is zero inside the specimen: relative errors are undefined")

    def error_of(self, estimate: np.ndarray) -> float:
        """Relative error of deviatoric tensors ``estimate`` (N, 6) at the probe's points."""
        return float(np.sqrt((tensor_norm(estimate - self.reference) ** 2).sum()) / self.scale)

    def __call__(self, field: StressField) -> float:
        return self.error_of(deviatoric_part(sample(field, self.points)))


def representation_floor(field: TrainableField, truth: StressField, points: np.ndarray) -> float | None:
    """The deviatoric error of ``truth`` itself sampled into a grid like ``field`` (the best grid,
    :func:`best_fit_floor`, does better near stress concentrations).

    Only on a lattice (a grid, or a network sampled on one; None otherwise): singular fields (point loads) keep a
    perfect reconstruction far from zero error at a finite resolution.
    """
    if not getattr(field, "lattice", False):
        return None
    nodes = deviatoric_part(sample(truth, grid_nodes(field.bbox_min, field.bbox_max, field.shape)))
    return _grid_error(field, stored_components(nodes, field.stress_scale), truth, points)


def best_fit_floor(field: TrainableField, truth: StressField, scene: mi.Scene, shapes: list[mi.Shape],
                   points: np.ndarray, fit_points_per_axis: int = 3 * EVALUATION_POINTS) -> float | None:
    """The deviatoric error at ``points`` of the least-squares fit of ``truth`` by a grid like ``field`` on a
    lattice ``fit_points_per_axis`` fine: the volume's best grid, near stress concentrations far better than
    the nodal values (:func:`representation_floor`). Only on a lattice (None otherwise)."""
    if not getattr(field, "lattice", False):
        return None
    return _grid_error(field, fitted_nodes(field, truth, evaluation_points(scene, shapes, fit_points_per_axis)),
                       truth, points)


def grid_floor(field: TrainableField, truth: StressField, points: np.ndarray) -> float | None:
    """The lowest deviatoric error that any grid like ``field`` can score at ``points``: the least-squares fit
    of ``truth`` at those very points. The error is one L2 norm over the same points, and a node's five stored
    components enter it through one positive-definite form shared by every point, so the componentwise fit
    minimises it: no optimiser of this grid scores lower (up to the solver's tolerance). Only on a lattice."""
    if not getattr(field, "lattice", False):
        return None
    return _grid_error(field, fitted_nodes(field, truth, points), truth, points)


def floor_bounds_nothing(field: TrainableField, floor: float, points: int) -> bool:
    """Whether a :func:`grid_floor` of ``floor`` over ``points`` evaluation points says nothing: a grid with at
    least as many nodes as points can pass through the truth at every one of them, and a floor of (nearly) zero
    then tells only that."""
    return floor < FLOOR_OF_A_FIT_THROUGH_EVERY_POINT and points <= int(np.prod(field.shape))


def fitted_nodes(field: TrainableField, truth: StressField, fit_points: np.ndarray) -> np.ndarray:
    """The nodes (five stored components, x fastest) of the grid like ``field`` that fits ``truth`` at
    ``fit_points`` in the least-squares sense (:func:`nodes_fitting` of its stress there)."""
    return nodes_fitting(field, sample(truth, fit_points), fit_points)


def nodes_fitting(field: TrainableField, stress: np.ndarray, fit_points: np.ndarray) -> np.ndarray:
    """The nodes of the grid like ``field`` whose deviator fits ``stress`` (``(N, 6)`` MPa) at ``fit_points`` in the
    least-squares sense: the normal equations, factorised once for the five components (an iterative solver took
    minutes where nodes touch the points with tiny weights, as in the kitten's ears)."""
    import scipy.sparse
    import scipy.sparse.linalg
    target = stored_components(deviatoric_part(stress), field.stress_scale)
    basis = trilinear_basis(fit_points, field.bbox_min, field.bbox_max, field.shape).tocsr()
    normal = (basis.T @ basis).tocsc()
    diagonal = normal.diagonal()
    # Nodes no point sees stay at zero; a whisper on the others keeps the system definite where points leave it
    # singular, far below any error that matters.
    normal = normal + scipy.sparse.diags(np.where(diagonal > 0, 1e-9 * diagonal.max(), 1.0))
    return scipy.sparse.linalg.splu(normal).solve(np.asarray(basis.T @ target))


def _grid_error(field, nodes, truth, points):
    """The deviatoric error of a grid like ``field`` holding ``nodes`` (its five stored components, x fastest)."""
    from .fields import DeviatoricGrid
    copy = DeviatoricGrid(field.config, field.bbox_min, field.bbox_max, field.stress_scale)
    copy.set_nodes(nodes)
    return stress_errors(copy, truth, points).deviatoric


def trilinear_basis(points: np.ndarray, bbox_min: np.ndarray, bbox_max: np.ndarray,
                    shape: tuple[int, int, int]) -> scipy.sparse.csr_matrix:
    """Sparse ``(N, nx * ny * nz)`` weights of trilinear interpolation from a nodal grid spanning the box."""
    import scipy.sparse
    shape = np.asarray(shape)
    u = (np.asarray(points) - bbox_min) / (np.asarray(bbox_max) - bbox_min) * (shape - 1)
    low = np.clip(np.floor(u).astype(np.int64), 0, shape - 2)
    f = np.clip(u - low, 0.0, 1.0)
    rows, columns, weights = [], [], []
    for corner in np.ndindex(2, 2, 2):
        corner = np.array(corner)
        weights.append(np.prod(np.where(corner, f, 1 - f), axis=1))
        node = low + corner
        columns.append(node[:, 0] + shape[0] * (node[:, 1] + shape[1] * node[:, 2]))
        rows.append(np.arange(len(u)))
    return scipy.sparse.csr_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(columns))),
                                   shape=(len(u), int(np.prod(shape))))


def psnr(predicted: np.ndarray, measured: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Peak signal-to-noise ratio (dB) of normalised intensities (peak 1) over ``mask``."""
    predicted, measured = np.asarray(predicted, np.float64), np.asarray(measured, np.float64)
    if mask is not None:
        predicted, measured = predicted[mask], measured[mask]
    mse = np.mean((predicted - measured) ** 2)
    return float("inf") if mse == 0 else float(10.0 * np.log10(1.0 / mse))
