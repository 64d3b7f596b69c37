"""Where to trust a reconstruction, node by node: how far the field is from balancing itself, how the data
observe each node, and how well the field explains the views it was not fitted to.

These are measured on a lattice over the specimen (a grid's own nodes):

- ``imbalance``: the equilibrium residual ``|div(s) + grad(p)|`` the reconstructed deviator ``s`` leaves with
  the mean stress ``p`` that balances it best (:mod:`~mi_nest.reconstruct.equilibrium`), the largest of the
  cells around the node, averaged over its 3 x 3 x 3 neighbourhood (stress scales per box length). A true field
  leaves only its discretisation; a wrong one does not balance;
- ``inside_share``: the share of the node's eight cells inside the specimen (1 deep inside, less on the surface);
- ``uncertainty``, the imbalance over the inside share: a node on the surface is held by the balance of fewer
  cells, and the free surface's traction is not asked of it, so the same imbalance leaves it freer to be wrong.
  On the accuracy suite it ranks the actual error with Spearman correlations of 0.74 to 0.80 on the kitten and
  the bracket and 0.41 to 0.55 on the disks, a few hundredths above the imbalance alone on six of seven
  results (``benchmarks/trust_ranking.py``, docs/reconstruction.md "Where to trust it"). Where other runs of
  the same data with other seeds lie beside it (``mi-nest spread``), it is also multiplied by one plus the
  node's ``seed_spread`` over its median: the error that is the seed's, which one run cannot see;
- ``seed_spread`` (given other runs): ``sqrt(mean |dev(s) - dev(s_other)|^2 / 2)`` over the other runs (MPa),
  the deviator's spread from seed to seed as seen from this run;
- ``coverage``: the share of the training views whose specimen pixels have a ray through the node;
- ``direction_spread``: ``3 lambda_min`` of the mean ``d d^T`` over those rays (1: directions from all around,
  0: all in one plane, where the tomography cannot tell some components apart);
- ``heldout_residual``: the mean L1 error of the 16 intensities of the held-out pixels whose rays cross the node;
- ``curvature_spread`` (grids): a spread estimate from the loss's curvature, ``1 / sqrt`` of the node's mean
  squared gradient over the run's last steps (Adam's second moment), relative to its median.

Rays are the cameras' straight lines, sampled along the box at a fraction of the node spacing and splatted to
the nearest node; refraction bends them in the data, not here (a measure of observation, not a render).
The uncertainty is relative (a ranking of the nodes by how far to trust them), not an error bar in MPa; the
other terms ranked the error far worse (the curvature spread -0.30 to 0.49, the observation terms and the
held-out residual -0.18 to 0.74 but mostly below 0.4) and are reported beside it.
"""
from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from scipy.ndimage import distance_transform_edt, uniform_filter

from ..arrays import device_array
from ..dataset import Dataset
from ..fields.base import sample
from ..io.atomic import atomic_path
from ..io.grid import grid_nodes
from . import equilibrium
from .evaluation import view_mask
from ..physics.tensors import deviatoric_part, tensor_norm
from .fields import TrainableField, grid_shape, stored_components
from .rays import ViewRays

# Training views sampled for the coverage (evenly over the split): enough to see every direction of the rig.
COVERAGE_VIEWS = 48
# Lattice nodes along the longest axis for representations without nodes of their own (MLPs, hash grids).
LATTICE = 48
# Samples along each ray per node spacing.
SAMPLES_PER_SPACING = 2
TRUST_FILE = "trust.npz"
# What reading a damaged trust.npz raises (cut short, edited, another program's).
READ_ERRORS = (ValueError, KeyError, OSError, EOFError, zipfile.BadZipFile)
# What a trust map holds per node, the uncertainty first.
TERMS = ("uncertainty", "imbalance", "inside_share", "seed_spread", "coverage", "direction_spread",
         "heldout_residual", "curvature_spread")
# The optional terms, in the order a map stores and loads them.
OPTIONAL_TERMS = ("curvature_spread", "inside_share", "seed_spread")


@dataclass
class TrustMap:
    """Per-node trust on a lattice ``shape = (nx, ny, nz)`` over ``bbox``; arrays (nz, ny, nx), NaN outside
    what any ray reached."""
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    coverage: np.ndarray
    direction_spread: np.ndarray
    heldout_residual: np.ndarray
    imbalance: np.ndarray
    view_residuals: list          # the held-out views' mean L1 residual over their specimen pixels
    views: list                   # their rotation positions
    # Grids: 1 / sqrt of the mean squared loss gradient per node, relative to its median (None for networks, and
    # in maps written before it): a spread estimate from the loss's curvature.
    curvature_spread: np.ndarray | None = None
    # The share of each node's eight cells inside the specimen (None in maps written before it).
    inside_share: np.ndarray | None = None
    # The deviator's spread over other runs of the same data (MPa; None until ``mi-nest spread`` gives some).
    seed_spread: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int, int]:
        nz, ny, nx = self.coverage.shape
        return nx, ny, nz

    @property
    def uncertainty(self) -> np.ndarray:
        """How far to trust each node, higher less: its :attr:`imbalance` over its :attr:`inside_share`. A node
        on the surface is held by the balance of fewer cells, and the free surface's traction is not asked of
        it, so the same imbalance there leaves the field freer to be wrong. With a :attr:`seed_spread`, times one
        plus the node's spread over its median: where the runs disagree, the seed's error adds to what the balance
        tells, and where they agree the balance still ranks the nodes (an error both runs share, such as a
        branch both took, does not vanish from the map)."""
        uncertainty = self.imbalance
        if self.inside_share is not None:
            uncertainty = uncertainty / np.where(self.inside_share > 0, self.inside_share, np.nan)
        if self.seed_spread is not None:
            uncertainty = uncertainty * (1.0 + self.seed_spread / self.seed_spread_median)
        return uncertainty

    @property
    def seed_spread_median(self) -> float:
        """The :attr:`seed_spread`'s median over the nodes the imbalance was measured at (MPa)."""
        return float(np.nanmedian(self.seed_spread[np.isfinite(self.imbalance)]))

    def nodes(self) -> np.ndarray:
        """Node positions (nz * ny * nx, 3), x fastest."""
        return grid_nodes(self.bbox_min, self.bbox_max, self.shape)

    def at(self, points: np.ndarray, name: str = "uncertainty") -> np.ndarray:
        """``name`` at ``points`` (N, 3), from the nearest node; a node the term was not measured at (a cell
        outside the part, a node no ray reached) takes its nearest measured node's value."""
        values = getattr(self, name)
        if values is None:
            return np.full(len(points), np.nan)
        measured = np.isfinite(values)
        if not measured.any():
            return np.full(len(points), np.nan)
        nearest = distance_transform_edt(~measured, return_distances=False, return_indices=True)
        filled = values[tuple(nearest)]
        low, high = np.asarray(self.bbox_min), np.asarray(self.bbox_max)
        counts = np.array(self.shape)
        index = np.rint((np.asarray(points) - low) / (high - low) * (counts - 1)).astype(int)
        index = np.clip(index, 0, counts - 1)
        return filled[index[:, 2], index[:, 1], index[:, 0]]

    def terms(self) -> list[str]:
        """The :data:`TERMS` this map holds (a network's has no curvature spread)."""
        return [name for name in TERMS if getattr(self, name) is not None]

    def point_data(self, points: np.ndarray) -> dict[str, np.ndarray]:
        """The terms at ``points`` under the names an export writes them (``trust_uncertainty``...)."""
        return {f"trust_{name}": self.at(points, name) for name in self.terms()}

    def summary(self) -> dict:
        """What ``reconstruction.json`` records."""
        seen = np.isfinite(self.imbalance)
        uncertainty = self.uncertainty[seen]
        summary = {"nodes": int(seen.sum()),
                   "uncertainty_median": _quantile(uncertainty, 0.5), "uncertainty_p95": _quantile(uncertainty, 0.95),
                   "coverage_median": _quantile(self.coverage[seen], 0.5),
                   "poorly_observed_share": float(np.mean(self.direction_spread[seen] < 0.1)) if seen.any() else 0.0,
                   "heldout_residual_by_view": dict(zip(map(str, self.views), np.round(self.view_residuals, 5)))}
        if self.seed_spread is not None:
            summary["seed_spread_median"] = self.seed_spread_median
            summary["seed_spread_p95"] = _quantile(self.seed_spread[seen], 0.95)
        return summary

    def save(self, path: str | Path) -> None:
        with atomic_path(Path(path), ".npz") as tmp:
            np.savez_compressed(tmp, bbox_min=self.bbox_min, bbox_max=self.bbox_max, coverage=self.coverage,
                                direction_spread=self.direction_spread, heldout_residual=self.heldout_residual,
                                imbalance=self.imbalance,
                                view_residuals=np.asarray(self.view_residuals), views=np.asarray(self.views),
                                **{name: getattr(self, name) for name in OPTIONAL_TERMS
                                   if getattr(self, name) is not None})

    @classmethod
    def load(cls, path: str | Path) -> TrustMap:
        with np.load(path) as data:
            return cls(data["bbox_min"], data["bbox_max"], data["coverage"], data["direction_spread"],
                       data["heldout_residual"], data["imbalance"], data["view_residuals"].tolist(),
                       data["views"].tolist(), *(data[name] if name in data else None for name in OPTIONAL_TERMS))


def _quantile(values, q):
    return float(np.quantile(values, q)) if values.size else float("nan")


def lattice_of(field: TrainableField) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]]:
    """The nodes trust is measured on: a grid's own, else a lattice of :data:`LATTICE` along the longest axis."""
    shape = getattr(field, "shape", None) or grid_shape(LATTICE, field.bbox_max - field.bbox_min)
    return np.asarray(field.bbox_min, float), np.asarray(field.bbox_max, float), tuple(shape)


def trust_map(scene: mi.Scene, dataset: Dataset, field: TrainableField, predictions: dict[int, np.ndarray],
              mask: str | None = "mask.dolp", second_moment: np.ndarray | None = None) -> TrustMap:
    """The :class:`TrustMap` of ``field`` reconstructed from ``dataset``; ``predictions``: its intensities in the
    held-out views (:func:`~mi_nest.reconstruct.evaluation.heldout_predictions`); ``second_moment``: a grid's
    Adam second moment at the end of its run, its nodes' five components in the grid's order (flat or
    (nz, ny, nx, 5)), for the curvature spread."""
    low, high, shape = lattice_of(field)
    splat = _Splat(low, high, shape)
    view_rays = ViewRays(scene, dataset)
    train = np.asarray(dataset.split("train"))
    chosen = train[np.unique(np.linspace(0, len(train) - 1, min(COVERAGE_VIEWS, len(train))).astype(int))]
    seen_by = np.zeros(splat.nodes)
    directions = np.zeros((splat.nodes, 6))
    for position in chosen:
        rays, _ = view_rays.view(int(position))
        selected = _pixels(dataset, int(position), mask)
        hits, outer = splat.directions(rays, selected)
        seen_by += hits > 0
        directions += outer
    residual_sum = np.zeros(splat.nodes)
    weight_sum = np.zeros(splat.nodes)
    view_residuals, views = [], []
    for position, predicted in predictions.items():
        error = np.abs(predicted - dataset.measurements(position).reshape(-1, len(dataset.channels))).mean(axis=1)
        selected = _pixels(dataset, position, mask)
        rays, _ = view_rays.view(position)
        total, weight = splat.values(rays, selected, error)
        residual_sum += total
        weight_sum += weight
        view_residuals.append(float(error[selected].mean()) if selected.any() else float("nan"))
        views.append(int(position))
    nx, ny, nz = shape
    samples = directions[:, :3].sum(axis=1)         # the trace of a sum of d d^T: the samples deposited
    reached = samples > 0
    tensor = directions[:, [0, 3, 5, 3, 1, 4, 5, 4, 2]].reshape(-1, 3, 3) / np.maximum(samples, 1e-30)[:, None, None]
    spread = 3.0 * np.clip(np.linalg.eigvalsh(tensor)[:, 0], 0.0, None)
    residual = np.where(weight_sum > 0, residual_sum / np.maximum(weight_sum, 1e-30), np.nan)
    coverage = np.where(reached, seen_by / max(len(chosen), 1), 0.0)
    solver = equilibrium.MeanStressSolver(equilibrium.specimen_stencil(scene, shape, low, high))
    balance = imbalance(scene, field, shape, solver)
    curvature = None
    if second_moment is not None and np.size(second_moment) == 5 * balance.size:
        curvature = curvature_spread(np.reshape(second_moment, (*balance.shape, 5)), np.isfinite(balance))
    return TrustMap(low, high, coverage.reshape(nz, ny, nx), np.where(reached, spread, 0.0).reshape(nz, ny, nx),
                    residual.reshape(nz, ny, nx), balance, view_residuals, views, curvature,
                    inside_share(solver.stencil))


def inside_share(stencil: equilibrium.CellStencil) -> np.ndarray:
    """The share of each node's up to eight cells that ``stencil`` holds (lie inside the specimen), (nz, ny, nx):
    1 deep inside, 1/8 at a convex corner, 0 outside."""
    nx, ny, nz = stencil.shape
    cells = np.zeros((nz - 1, ny - 1, nx - 1))
    np.put(cells, stencil.cells, 1.0)
    return _node_cells(cells, 0.0).mean(axis=0)


def _node_cells(cells: np.ndarray, outside: float) -> np.ndarray:
    """Each node's up to eight cells' values (8, nz, ny, nx) from per-cell ``cells`` (nz - 1, ny - 1, nx - 1);
    ``outside`` where a node's cell lies beyond the lattice."""
    nz, ny, nx = (n + 1 for n in cells.shape)
    padded = np.pad(cells, 1, constant_values=outside)
    return np.stack([padded[a:a + nz, b:b + ny, c:c + nx] for a in (0, 1) for b in (0, 1) for c in (0, 1)])


def curvature_spread(second_moment: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """``1 / sqrt(mean v)`` per node over its five components, relative to its median over ``inside``; NaN
    elsewhere. With an L1 loss the minibatch gradient's mean square ``v`` (Adam's second moment, an average over
    about its last thousand steps) grows with how strongly the pixels pull on the node: a diagonal Fisher
    information, whose inverse square root is the node's spread."""
    strength = np.sqrt(np.asarray(second_moment, np.float64).mean(axis=-1))
    floor = 1e-12 * max(float(strength[inside].max()) if inside.any() else 0.0, 1e-30)
    spread = np.where(inside, 1.0 / np.maximum(strength, floor), np.nan)
    return spread / np.nanmedian(spread) if inside.any() else spread


def imbalance(scene: mi.Scene, field: TrainableField, shape: tuple[int, int, int],
              solver: equilibrium.MeanStressSolver | None = None) -> np.ndarray:
    """The :attr:`TrustMap.imbalance` of ``field`` on the lattice ``shape`` over its box (NaN at nodes no cell
    inside the specimen touches); ``solver``: the specimen's mean stress solver on that lattice, where the
    caller keeps one (None: built here)."""
    nx, ny, nz = shape
    if getattr(field, "shape", None) == tuple(shape):
        deviator = np.array(field.texture.tensor(), dtype=np.float64)
    else:
        stress = deviatoric_part(sample(field, grid_nodes(field.bbox_min, field.bbox_max, shape)))
        deviator = stored_components(stress, field.stress_scale).reshape(nz, ny, nx, 5)
    if solver is None:
        solver = equilibrium.MeanStressSolver(equilibrium.specimen_stencil(scene, shape, field.bbox_min,
                                                                           field.bbox_max))
    cells = np.full((nz - 1, ny - 1, nx - 1), np.nan)
    np.put(cells, solver.stencil.cells, np.sqrt(solver.cell_residuals(deviator)))
    # Each node takes the largest of its up to eight cells (an unbalanced cell taints all its corners).
    corners = _node_cells(cells, np.nan)
    touched = np.isfinite(corners).any(axis=0)
    largest = np.where(touched, np.nanmax(np.where(np.isfinite(corners), corners, -np.inf), axis=0), 0.0)
    # The neighbourhood's mean over the touched nodes only.
    total = uniform_filter(largest, 3, mode="constant")
    count = uniform_filter(touched.astype(float), 3, mode="constant")
    return np.where(touched, total / np.maximum(count, 1e-12), np.nan)


def _pixels(dataset, position, mask):
    selected = view_mask(dataset, position, mask)
    width, height = dataset.resolution
    return np.ones(width * height, bool) if selected is None else selected


class _Splat:
    """Straight rays sampled across a box and deposited on its nearest lattice nodes."""

    def __init__(self, low, high, shape):
        self.low, self.high, self.shape = low, high, shape
        self.nodes = int(np.prod(shape))
        spacing = float(np.min((high - low) / (np.array(shape) - 1)))
        self.step = spacing / SAMPLES_PER_SPACING
        self.count = int(np.ceil(np.linalg.norm(high - low) / self.step)) + 1

    def _samples(self, rays: mi.Ray3f, selected: np.ndarray):
        """Per sample along the selected rays inside the box: node index, the ray's index, its direction."""
        index = np.flatnonzero(selected).astype(np.uint32)
        ray = dr.gather(mi.Ray3f, rays, device_array(mi.UInt32, index, np.uint32))
        box = mi.BoundingBox3f(mi.ScalarPoint3f(self.low), mi.ScalarPoint3f(self.high))
        hit, near, far = box.ray_intersect(ray)
        near = dr.maximum(near, 0.0)
        step = dr.arange(mi.UInt32, self.count)
        which = dr.repeat(dr.arange(mi.UInt32, len(index)), self.count) if len(index) else mi.UInt32()
        along = dr.tile(step, len(index))
        t = dr.gather(mi.Float, near, which) + (mi.Float(along) + 0.5) * self.step
        valid = dr.gather(mi.Bool, hit, which) & (t < dr.gather(mi.Float, far, which))
        o, d = dr.gather(mi.Point3f, ray.o, which), dr.gather(mi.Vector3f, ray.d, which)
        p = o + t * d
        last = [float(n - 1) for n in self.shape]
        u = (p - mi.ScalarPoint3f(self.low)) / mi.ScalarVector3f(self.high - self.low)
        i = [mi.UInt32(dr.clip(dr.round(u[axis] * last[axis]), 0.0, last[axis])) for axis in range(3)]
        node = i[0] + self.shape[0] * (i[1] + self.shape[1] * i[2])
        return node, which, d, valid

    def directions(self, rays, selected):
        """Per node: samples deposited, and the sum of ``d d^T`` (xx, yy, zz, xy, yz, zx)."""
        if not selected.any():
            return np.zeros(self.nodes), np.zeros((self.nodes, 6))
        node, _, d, valid = self._samples(rays, selected)
        hits = dr.zeros(mi.Float, self.nodes)
        dr.scatter_reduce(dr.ReduceOp.Add, hits, 1.0, node, valid)
        outer = []
        for a, b in ((0, 0), (1, 1), (2, 2), (0, 1), (1, 2), (2, 0)):
            target = dr.zeros(mi.Float, self.nodes)
            dr.scatter_reduce(dr.ReduceOp.Add, target, d[a] * d[b], node, valid)
            outer.append(np.array(target))
        return np.array(hits), np.stack(outer, axis=1)

    def values(self, rays, selected, per_ray):
        """Per node: the sum of the rays' values over the samples deposited, and the samples' count."""
        if not selected.any():
            return np.zeros(self.nodes), np.zeros(self.nodes)
        node, which, _, valid = self._samples(rays, selected)
        value = dr.gather(mi.Float, device_array(mi.Float, per_ray[selected].astype(np.float32)), which)
        total, weight = dr.zeros(mi.Float, self.nodes), dr.zeros(mi.Float, self.nodes)
        dr.scatter_reduce(dr.ReduceOp.Add, total, value, node, valid)
        dr.scatter_reduce(dr.ReduceOp.Add, weight, 1.0, node, valid)
        return np.array(total), np.array(weight)


def seed_spread(field: TrainableField, others: list[TrainableField], nodes: np.ndarray) -> np.ndarray:
    """:attr:`TrustMap.seed_spread` of ``field`` at ``nodes`` (N, 3) from ``others``, runs of the same data with
    other seeds: ``sqrt(mean |dev(s) - dev(s_other)|^2 / 2)`` (MPa). Two runs whose errors are independent and
    alike differ by sqrt(2) times that error, and this run's own error is part of each difference."""
    squared = sum(error_map(field, other, nodes) ** 2 for other in others)
    return np.sqrt(squared / (2 * len(others)))


def error_map(field: TrainableField, truth, nodes: np.ndarray) -> np.ndarray:
    """The deviatoric error norm ``|s - s_true|`` (MPa) at ``nodes``: what the uncertainty should rank."""
    return tensor_norm(deviatoric_part(sample(field, nodes)) - deviatoric_part(sample(truth, nodes)))
