"""Equilibrium as a prior on a grid: ``div(s) + grad(p) = 0`` inside the specimen.

A body without body forces satisfies ``div(sigma) = 0``. Photoelasticity sees only the deviator ``s``; the mean
stress ``p`` (``sigma = s + p I``) is invisible to the images, so the grid carries it as a free unknown that
only this penalty acts on. Equilibrium then asks that ``div(s)`` be a gradient: two of its three components per
point constrain the five deviatoric ones, which removes much of the tomography's null space; ``p`` comes out
as the mean stress the deviator implies (up to a constant).

The residual is taken at the centres of the cells whose centre lies inside the specimen, each derivative from
the cell's eight corner nodes (the trilinear field's own derivative there, averaged over the cell's faces), so
the deviator and the mean stress share one stencil. Lengths are in units of the box's longest side and stresses
in stress scales, as for the smoothness: one weight serves every specimen and resolution.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

# The stored deviatoric channels (xx, yy, yz, zx, xy) in each row of div(s), as (channel, axis of the derivative,
# sign); zz = -(xx + yy) enters the z row through xx and yy.
_ROWS = (
    ((0, 0, 1.0), (4, 1, 1.0), (3, 2, 1.0)),                    # d sxx/dx + d sxy/dy + d szx/dz
    ((4, 0, 1.0), (1, 1, 1.0), (2, 2, 1.0)),                    # d sxy/dx + d syy/dy + d syz/dz
    ((3, 0, 1.0), (2, 1, 1.0), (0, 2, -1.0), (1, 2, -1.0)),     # d szx/dx + d syz/dy + d szz/dz
)


@dataclass(frozen=True)
class CellStencil:
    """The cells of a ``(nx, ny, nz)`` node grid where equilibrium is asked, as the flat index of each cell's
    lowest corner node, and the node spacing per axis (units of the box's longest side)."""
    shape: tuple[int, int, int]
    corners: np.ndarray          # (cells,) uint32: node index (x fastest) of each cell's lowest corner
    cells: np.ndarray            # (cells,) uint32: the same cells' indices among all the grid's cells
    spacing: np.ndarray          # (3,)

    @classmethod
    def of(cls, shape: tuple[int, int, int], extent: np.ndarray, inside_cells: np.ndarray) -> CellStencil:
        """``inside_cells`` (nz - 1, ny - 1, nx - 1) bool: where the specimen is (its cell centres)."""
        nx, ny, nz = shape
        inside_cells = np.asarray(inside_cells, dtype=bool)
        if inside_cells.shape != (nz - 1, ny - 1, nx - 1):
            raise ValueError(f"inside_cells has shape {inside_cells.shape}, a {nx}x{ny}x{nz} grid has "
                             f"{(nz - 1, ny - 1, nx - 1)} cells")
        k, j, i = np.nonzero(inside_cells)
        extent = np.asarray(extent, dtype=np.float64)
        spacing = extent / extent.max() / (np.array(shape) - 1)
        return cls(tuple(shape), (i + nx * (j + ny * k)).astype(np.uint32),
                   (i + (nx - 1) * (j + (ny - 1) * k)).astype(np.uint32), spacing)


def specimen_stencil(scene: mi.Scene, shape: tuple[int, int, int], bbox_min: np.ndarray,
                     bbox_max: np.ndarray) -> CellStencil:
    """The stencil of a node grid's cells whose centres lie inside ``scene``'s specimens."""
    from ..occupancy import inside
    from ..scene import specimen_shapes
    centres = cell_centres(shape, bbox_min, bbox_max)
    occupied = inside(scene, specimen_shapes(scene), centres.reshape(-1, 3)).reshape(centres.shape[:3])
    return CellStencil.of(shape, np.asarray(bbox_max) - np.asarray(bbox_min), occupied)


def cell_centres(shape: tuple[int, int, int], bbox_min: np.ndarray, bbox_max: np.ndarray) -> np.ndarray:
    """The centres (mm) of a node grid's cells, (nz - 1, ny - 1, nx - 1, 3), x fastest."""
    axes = [np.linspace(lo, hi, n)[:-1] + (hi - lo) / (n - 1) / 2 for lo, hi, n in zip(bbox_min, bbox_max, shape)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    return np.stack([x, y, z], axis=-1)


def residual(deviator: mi.Float, mean: mi.Float, stencil: CellStencil) -> list[mi.Float]:
    """``div(s) + grad(p)`` at the stencil's cells, three components: ``deviator`` the grid's flat (z, y, x, 5)
    values, ``mean`` its flat (z, y, x) mean stress."""
    nx, ny, _ = stencil.shape
    corner = mi.UInt32(stencil.corners)
    strides = (1, nx, nx * ny)
    # The derivative along an axis at a cell's centre: the differences across the cell along that axis, averaged
    # over the four edges they lie on.
    edges = [[(a * strides[(axis + 1) % 3] + b * strides[(axis + 2) % 3]) for a in (0, 1) for b in (0, 1)]
             for axis in range(3)]

    def derivative(values, channels, channel, axis):
        total = 0.0
        for offset in edges[axis]:
            low = corner + offset
            high = low + strides[axis]
            total += dr.gather(mi.Float, values, high * channels + channel) - \
                dr.gather(mi.Float, values, low * channels + channel)
        return total * float(0.25 / stencil.spacing[axis])

    rows = []
    for axis, row in enumerate(_ROWS):
        value = derivative(mean, 1, 0, axis)
        for channel, along, sign in row:
            value = value + sign * derivative(deviator, 5, channel, along)
        rows.append(value)
    return rows


def penalty(deviator: mi.Float, mean: mi.Float, stencil: CellStencil, weight: float | mi.Float) -> mi.Float:
    """``weight`` times the mean over the stencil's cells of ``|div(s) + grad(p)|^2`` (a term of the loss)."""
    if len(stencil.corners) == 0:
        return mi.Float(0.0)
    return dr.custom(_Balance, deviator, mean, stencil, weight)


class _Balance(dr.CustomOp):
    """:func:`penalty` with its gradient gathered per node from the eight cells around it, in one kernel:
    differentiated automatically, every cell scattered its derivative to its corners by atomic adds, which
    doubled the time of an iteration on the disk's coarse grids."""

    def eval(self, deviator, mean, stencil, weight):
        self.stencil, self.weight = stencil, weight
        self.widths = (dr.width(deviator), dr.width(mean))
        rows = residual(deviator, mean, stencil)
        nx, ny, nz = stencil.shape
        cells = (nx - 1) * (ny - 1) * (nz - 1)
        # Every cell's residual in a dense array (zero outside the stencil), for the nodes to gather from.
        self.dense = dr.zeros(mi.Float, 3 * cells)
        index = mi.UInt32(stencil.cells)
        for axis, row in enumerate(rows):
            dr.scatter(self.dense, row, index + axis * cells)
        return weight * dr.mean(sum(dr.square(row) for row in rows))

    def backward(self):
        stencil = self.stencil
        nx, ny, nz = stencil.shape
        cells = (nx - 1) * (ny - 1) * (nz - 1)
        node = dr.arange(mi.UInt32, self.widths[1])
        i, j, k = node % nx, (node // nx) % ny, node // (nx * ny)
        # across[row][axis]: the residual's row summed over the node's cells, each signed by the side of the cell
        # the node sits on along the axis (what the transposed derivative stencil gives the node).
        across = [[0.0, 0.0, 0.0] for _ in range(3)]
        for a in (0, 1):
            for b in (0, 1):
                for c in (0, 1):
                    valid = (i >= a) & (i - a < nx - 1) & (j >= b) & (j - b < ny - 1) & (k >= c) & (k - c < nz - 1)
                    cell = (i - a) + (nx - 1) * ((j - b) + (ny - 1) * (k - c))
                    for row in range(3):
                        value = dr.gather(mi.Float, self.dense, cell + row * cells, valid)
                        for axis, side in enumerate((a, b, c)):
                            across[row][axis] = across[row][axis] + (value if side else -value)
        scale = self.grad_out() * self.weight * 2.0 / len(stencil.corners) * 0.25
        per_axis = [scale / float(h) for h in stencil.spacing]
        self.set_grad_in("mean", sum(across[axis][axis] * per_axis[axis] for axis in range(3)))
        channels = [0.0] * 5
        for row, terms in enumerate(_ROWS):
            for channel, along, sign in terms:
                channels[channel] = channels[channel] + sign * across[row][along] * per_axis[along]
        gradient = dr.zeros(mi.Float, self.widths[0])
        for channel, value in enumerate(channels):
            dr.scatter(gradient, value, node * 5 + channel)
        self.set_grad_in("deviator", gradient)

    def name(self):
        return "Balance"


def residual_numpy(deviator: np.ndarray, mean: np.ndarray, stencil: CellStencil) -> np.ndarray:
    """:func:`residual` in NumPy, (cells, 3): ``deviator`` (nz, ny, nx, 5), ``mean`` (nz, ny, nx)."""
    values = np.concatenate([np.asarray(deviator, np.float64), np.asarray(mean, np.float64)[..., None]], axis=-1)

    def derivative(channel, axis):
        moved = np.moveaxis(values[..., channel], 2 - axis, 0)
        difference = np.diff(moved, axis=0)
        # average over the cell's four edges along this axis
        for other in (1, 2):
            difference = 0.5 * (np.take(difference, range(difference.shape[other] - 1), axis=other)
                                + np.take(difference, range(1, difference.shape[other]), axis=other))
        return np.moveaxis(difference, 0, 2 - axis) / stencil.spacing[axis]

    nx, ny, _ = stencil.shape
    i = stencil.corners % nx
    j = (stencil.corners // nx) % ny
    k = stencil.corners // (nx * ny)
    rows = []
    for axis, row in enumerate(_ROWS):
        total = derivative(5, axis)
        for channel, along, sign in row:
            total = total + sign * derivative(channel, along)
        rows.append(total[k, j, i])
    return np.stack(rows, axis=-1)


class MeanStressSolver:
    """The mean stress that best balances a deviator on one stencil: the penalty's minimum over ``p``, a
    Poisson-like least-squares problem, set up once (algebraic multigrid, pyamg) and solved per deviator by
    preconditioned conjugate gradients.

    The cell-centred gradient does not see a node-to-node checkerboard of ``p``, so the normal equations are
    singular (consistently: conjugate gradients from zero never excite it). Multigrid cannot coarsen them as
    they are; it preconditions them with a faint penalty on nearest-neighbour differences added
    (:data:`CHECKERBOARD` of the balance's weight), which the solve itself does not carry, so the smooth part is
    not bent. Tens of iterations; a direct factorisation took 8 minutes on a 64 x 64 x 33 grid."""

    CHECKERBOARD = 1e-3
    # Enough for the prior and the trust map alike: a solve warm-started to 1e-4 left the same residual to seven
    # digits as one to 1e-8 (0.13 s against 2.5 s on the 300 N disk's 64 x 64 x 11 grid); from zero, the 600 N
    # disk's RMS residual the same to six digits as at 1e-6 and every node's imbalance within 0.3%, in an eighth
    # of the time.
    PRACTICAL_TOLERANCE = 1e-4

    def __init__(self, stencil: CellStencil):
        import pyamg
        self.stencil = stencil
        gradient = _gradient_matrix(stencil)
        self.touched = np.flatnonzero(np.asarray(abs(gradient).sum(axis=0)).ravel() > 0)
        self.gradient = gradient[:, self.touched].tocsr()
        self.solver = None
        if len(self.touched):
            differences = _difference_matrix(stencil)[:, self.touched]
            self.normal = (self.gradient.T @ self.gradient).tocsr()
            definite = (self.normal + self.CHECKERBOARD * (differences.T @ differences)).tocsr()
            self.solver = pyamg.smoothed_aggregation_solver(definite, symmetry="symmetric").aspreconditioner()

    def solve(self, deviator: np.ndarray, start: np.ndarray | None = None,
              tolerance: float = 1e-6) -> tuple[np.ndarray, float]:
        """The mean stress (nz, ny, nx) for ``deviator`` (nz, ny, nx, 5), zero at nodes no cell touches, and the
        RMS residual it leaves (what the prior charges the deviator); ``start``: a guess (the last solve's),
        ``tolerance``: of the normal equations' relative residual."""
        import scipy.sparse.linalg
        nx, ny, nz = self.stencil.shape
        mean = np.zeros(nx * ny * nz)
        if self.solver is None:
            return mean.reshape(nz, ny, nx), 0.0
        unbalanced = residual_numpy(deviator, np.zeros((nz, ny, nx)), self.stencil).T.ravel()
        guess = None if start is None else np.asarray(start, dtype=np.float64).ravel()[self.touched]
        solution, _ = scipy.sparse.linalg.cg(self.normal, -(self.gradient.T @ unbalanced), x0=guess,
                                             rtol=tolerance, maxiter=200, M=self.solver)
        mean[self.touched] = solution
        left = unbalanced + self.gradient @ solution
        return mean.reshape(nz, ny, nx), float(np.sqrt(np.sum(left ** 2) / len(self.stencil.corners)))

    def cell_residuals(self, deviator: np.ndarray, tolerance: float = PRACTICAL_TOLERANCE) -> np.ndarray:
        """Each of the stencil's cells' squared residual ``|div(s) + grad(p)|^2`` (``stencil.cells`` order) with the
        mean stress ``p`` that best balances ``deviator`` (nz, ny, nx, 5): where a field is out of balance."""
        mean, _ = self.solve(deviator, tolerance=tolerance)
        return np.sum(residual_numpy(deviator, mean, self.stencil) ** 2, axis=1)


def _gradient_matrix(stencil: CellStencil):
    """The sparse (3 cells, nodes) operator of :func:`residual`'s ``grad(p)``, rows grouped by component."""
    import scipy.sparse
    nx, ny, nz = stencil.shape
    strides = (1, nx, nx * ny)
    cells = len(stencil.corners)
    rows, columns, values = [], [], []
    for axis in range(3):
        for a in (0, 1):
            for b in (0, 1):
                low = stencil.corners + a * strides[(axis + 1) % 3] + b * strides[(axis + 2) % 3]
                for node, sign in ((low + strides[axis], 1.0), (low, -1.0)):
                    rows.append(axis * cells + np.arange(cells))
                    columns.append(node)
                    values.append(np.full(cells, sign * 0.25 / stencil.spacing[axis]))
    return scipy.sparse.csr_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(columns))),
                                   shape=(3 * cells, nx * ny * nz))


def _difference_matrix(stencil: CellStencil):
    """The sparse operator of the differences per spacing between neighbouring nodes, every axis."""
    import scipy.sparse
    nx, ny, nz = stencil.shape
    index = np.arange(nx * ny * nz).reshape(nz, ny, nx)
    blocks = []
    for axis, spacing in enumerate(stencil.spacing):
        count = index.shape[2 - axis]
        low = np.take(index, range(count - 1), axis=2 - axis).ravel()
        high = np.take(index, range(1, count), axis=2 - axis).ravel()
        rows = np.arange(len(low))
        blocks.append(scipy.sparse.csr_matrix(
            (np.r_[np.full(len(low), 1.0 / spacing), np.full(len(low), -1.0 / spacing)],
             (np.r_[rows, rows], np.r_[high, low])), shape=(len(low), nx * ny * nz)))
    return scipy.sparse.vstack(blocks).tocsr()
