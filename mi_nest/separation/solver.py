"""The mean stress a deviator implies, by equilibrium: a least-squares Poisson problem (scikit-fem, pyamg).

With no body forces ``div(sigma) = 0``; with ``sigma = s + p I`` that is ``grad p = -div s`` inside the part,
and on a free surface ``sigma n = 0`` gives ``p = -n.s.n``. Both overdetermine ``p``; the mean stress is the
minimiser of

    J(p) = int_part |grad p + div s|^2 dV + (1 / h) int_free (p + n.s.n)^2 dA

on trilinear (Q1) hexahedra over the cells of a lattice that meet the part, ``h`` the lattice spacing (so the
two terms weigh alike as the lattice is refined). The part is cut out of its cells by quadrature weights
(the inside share around each quadrature point), the free surface sampled by points with their areas; loaded
surfaces are left out (their traction is unknown), so only the interior equation acts there.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..io.grid import grid_nodes
from ..physics.tensors import stress_matrices
from .surface import Surface

# Weight of the gradient term on the parts of cut cells outside the part: keeps nodes that the part barely
# touches determined without bending the solution.
GHOST = 1e-4
# Iteratively reweighted least squares (Huber): a point load's neighbourhood, where no lattice resolves the
# deviator, leaves residuals thousands of times the typical; at full weight they set the whole part's mean stress.
ROBUST_PASSES = 3
HUBER = 3.0
# Inside tests per quadrature point of a cut cell (per axis, in the point's octant of the cell).
SUBSAMPLES = 2


@dataclass(frozen=True)
class Lattice:
    """Nodes ``shape = (nx, ny, nz)`` spanning ``[low, high]`` (mm) evenly."""
    low: np.ndarray
    high: np.ndarray
    shape: tuple[int, int, int]

    @property
    def spacing(self) -> np.ndarray:
        return (np.asarray(self.high) - np.asarray(self.low)) / (np.array(self.shape) - 1)

    def axes(self) -> list[np.ndarray]:
        return [np.linspace(self.low[i], self.high[i], self.shape[i]) for i in range(3)]

    def nodes(self) -> np.ndarray:
        """``(nz * ny * nx, 3)`` node positions, x fastest (a stress grid's order)."""
        return grid_nodes(self.low, self.high, self.shape)

    def flat_index(self, points: np.ndarray) -> np.ndarray:
        """The flat index of the lattice node at each of ``points`` (which must be nodes)."""
        ijk = np.rint((np.asarray(points) - self.low) / self.spacing).astype(np.int64)
        nx, ny, _ = self.shape
        return ijk[:, 0] + nx * (ijk[:, 1] + ny * ijk[:, 2])


@dataclass
class Solution:
    """The mean stress at the domain's nodes and what the solve left."""
    nodes: np.ndarray            # (M,) flat lattice indices of the domain's nodes
    mean: np.ndarray             # (M,) MPa
    interior_residual: float     # RMS of |grad p + div s| over the part, MPa/mm
    free_residual: np.ndarray    # (free points,) p + n.s.n, MPa
    free_traction: np.ndarray    # (free points, 3) (s + p I) n, MPa: what a free surface should not carry
    iterations: int
    cells: int


def _domain(lattice: Lattice, node_inside: np.ndarray, surface: Surface, free: Surface):
    """The lattice's cells that meet the part (a corner inside, or a surface point in them) and connect to a free
    surface (a piece without one has no mean stress to find), as a scikit-fem mesh, and which of its elements
    lie wholly inside."""
    import scipy.sparse
    from scipy.sparse.csgraph import connected_components
    from skfem import MeshHex
    mesh = MeshHex.init_tensor(*lattice.axes())
    corners = lattice.flat_index(mesh.p.T)[mesh.t]                       # (8, cells) lattice indices
    inside_corners = node_inside[corners]
    nx, ny, nz = lattice.shape
    cell_ijk = np.rint((mesh.p[:, mesh.t].min(axis=1).T - lattice.low) / lattice.spacing).astype(np.int64)
    cell_index = cell_ijk[:, 0] + (nx - 1) * (cell_ijk[:, 1] + (ny - 1) * cell_ijk[:, 2])
    chosen = inside_corners.any(axis=0) | _holding(lattice, surface.points)[cell_index]
    # Cells sharing a node are connected; keep the pieces that hold a free surface point.
    cells = np.flatnonzero(chosen)
    incidence = scipy.sparse.coo_matrix((np.ones(8 * len(cells)), (np.repeat(np.arange(len(cells)), 8),
                                         mesh.t[:, cells].T.ravel())), shape=(len(cells), mesh.p.shape[1])).tocsr()
    _, piece = connected_components(incidence @ incidence.T, directed=False)
    free_cells = _holding(lattice, free.points)[cell_index[cells]]
    keep = np.isin(piece, np.unique(piece[free_cells]))
    return mesh.restrict(cells[keep]), inside_corners.all(axis=0)[cells[keep]]


def _holding(lattice: Lattice, points: np.ndarray) -> np.ndarray:
    """Which of the lattice's cells (flat, x fastest) hold one of ``points``."""
    nx, ny, nz = lattice.shape
    ijk = np.clip(np.floor((points - lattice.low) / lattice.spacing).astype(np.int64), 0, np.array(lattice.shape) - 2)
    holding = np.zeros((nx - 1) * (ny - 1) * (nz - 1), dtype=bool)
    holding[ijk[:, 0] + (nx - 1) * (ijk[:, 1] + (ny - 1) * ijk[:, 2])] = True
    return holding


def _inside_share(basis, whole: np.ndarray, spacing: np.ndarray, inside) -> np.ndarray:
    """``(cells, quadrature points)``: the share of the part around each quadrature point (1 in whole cells)."""
    share = np.ones((basis.mesh.t.shape[1], basis.X.shape[1]))
    cut = np.flatnonzero(~whole)
    if len(cut) == 0:
        return share
    points = basis.mapping.F(basis.X)[:, cut, :]                         # (3, cut, qp)
    offsets = (np.arange(SUBSAMPLES) + 0.5) / SUBSAMPLES - 0.5
    grid = np.stack(np.meshgrid(offsets, offsets, offsets, indexing="ij"), axis=-1).reshape(-1, 3)
    # Each quadrature point of a 2 x 2 x 2 rule stands for its octant of the cell: test points spread there.
    around = points.T[:, :, None, :] + 0.5 * grid[None, None, :, :] * spacing
    tested = inside(around.reshape(-1, 3)).reshape(around.shape[:3])
    share[cut] = tested.mean(axis=-1).T
    return share


def solve_mean_stress(lattice: Lattice, node_inside: np.ndarray, deviator: np.ndarray, free: Surface,
                      surface: Surface, inside) -> Solution:
    """The mean stress on the cells of ``lattice`` that meet the part: ``deviator`` (nodes, 6) trace-free at
    every lattice node, ``free`` the free surface's points, ``surface`` all of it (its cells belong to the
    domain), ``inside(points) -> bool`` the part's inside test.

    Huber's weights per cell and per free-surface point, :data:`ROBUST_PASSES` times: the element matrices are
    computed once (scikit-fem) and only their weights change between passes."""
    import pyamg
    import scipy.sparse
    import scipy.sparse.linalg
    from skfem import Basis, BilinearForm, ElementHex1, LinearForm, MeshHex
    from skfem.helpers import dot, grad

    mesh, whole = _domain(lattice, node_inside, surface, free)
    basis = Basis(mesh, ElementHex1(), intorder=3)
    nodes = lattice.flat_index(mesh.p.T)
    s = deviator[nodes]
    share = _inside_share(basis, whole, lattice.spacing, inside)
    divergence = _divergence(basis, s)

    @BilinearForm
    def stiffness(u, v, w):
        return w.weight * dot(grad(u), grad(v))

    @LinearForm
    def load(v, w):
        return -w.weight * dot(w.f, grad(v))

    cells = mesh.t.shape[1]
    inner_local = stiffness.coo_data(basis, weight=share).data.reshape(8, 8, cells)
    load_local = load.coo_data(basis, weight=share, f=divergence).data.reshape(8, cells)
    volume = np.sum(basis.dx * share, axis=1)
    constant = np.sum(basis.dx * share * np.sum(divergence ** 2, axis=0), axis=1)
    # Every cell of the lattice is the same box: the ghost term is one element matrix, weighted by what is outside.
    one_cell = Basis(MeshHex.init_tensor(*[np.array([0.0, h]) for h in lattice.spacing]), ElementHex1(), intorder=3)
    outside = 1.0 - volume / np.max(basis.dx.sum(axis=1))
    cell_matrix = stiffness.coo_data(one_cell, weight=np.ones((1, basis.X.shape[1]))).data.reshape(8, 8, 1)
    ghost_local = GHOST * outside * cell_matrix
    dofs = basis.element_dofs
    rows = np.broadcast_to(dofs[:, None, :], (8, 8, cells)).ravel()
    columns = np.broadcast_to(dofs[None, :, :], (8, 8, cells)).ravel()

    h = float(lattice.spacing.max())
    probes = _trilinear(lattice, nodes, free.points)
    normal_stress = _normal_stress(probes @ s, free.normals)
    inner, outer = np.ones(cells), np.ones(len(free))
    mean, iterations = np.zeros(len(nodes)), 0
    for _ in range(ROBUST_PASSES):
        local = (inner_local * inner + ghost_local).ravel()
        matrix = scipy.sparse.csr_matrix((local, (rows, columns)), shape=(len(nodes), len(nodes))) + \
            probes.T @ scipy.sparse.diags(outer * free.areas / h) @ probes
        rhs = np.bincount(dofs.ravel(), weights=(load_local * inner).ravel(), minlength=len(nodes)) - \
            probes.T @ (outer * free.areas / h * normal_stress)
        # Multigrid for each pass's matrix: Huber's weights change it by orders of magnitude in places.
        preconditioner = pyamg.smoothed_aggregation_solver(matrix, symmetry="symmetric").aspreconditioner()
        steps = []
        mean, failed = scipy.sparse.linalg.cg(matrix, rhs, x0=mean, rtol=1e-10, maxiter=2000, M=preconditioner,
                                              callback=steps.append)
        iterations += len(steps)
        if failed or not np.all(np.isfinite(mean)):
            raise ArithmeticError(f"the mean stress's solve did not converge in {len(steps)} steps")
        local = mean[dofs]
        # int_cell share |grad p + div s|^2 from the element matrices: p K p - 2 p . load + c.
        energy = np.einsum("ie,ije,je->e", local, inner_local, local) - 2 * np.sum(local * load_local, axis=0) \
            + constant
        imbalance = np.sqrt(np.maximum(energy, 0.0) / np.maximum(volume, 1e-300))
        left = probes @ mean + normal_stress
        inner = _huber(imbalance, volume > 0.5 * np.max(volume))
        outer = _huber(np.abs(left) / h, np.ones(len(left), bool))
    rms = np.sqrt(np.sum(np.maximum(energy, 0.0)) / np.sum(volume))
    traction = np.einsum("nij,nj->ni", stress_matrices(probes @ s), free.normals) + \
        (probes @ mean)[:, None] * free.normals
    return Solution(nodes, mean, float(rms), left, traction, iterations, cells)


def _divergence(basis, s: np.ndarray) -> np.ndarray:
    """``(3, cells, quadrature points)`` divergence of the Q1 field of nodal tensors ``s`` (nodes, 6), from the
    basis functions' gradients that scikit-fem holds."""
    divergence = np.zeros((3,) + basis.basis[0][0].grad.shape[1:])
    # (row, tensor component, derivative axis) of div(s) with s = (xx, yy, zz, yz, zx, xy)
    terms = ((0, 0, 0), (0, 5, 1), (0, 4, 2), (1, 5, 0), (1, 1, 1), (1, 3, 2), (2, 4, 0), (2, 3, 1), (2, 2, 2))
    for local, dof in enumerate(basis.element_dofs):
        gradient = basis.basis[local][0].grad
        values = s[dof]
        for row, component, axis in terms:
            divergence[row] += values[:, component, None] * gradient[axis]
    return divergence


def _huber(residual: np.ndarray, typical: np.ndarray) -> np.ndarray:
    """Huber's weights: 1 up to :data:`HUBER` times the median residual (over ``typical``), falling as one over
    the residual beyond."""
    threshold = HUBER * np.median(residual[typical]) if typical.any() else 0.0
    if threshold <= 0:
        return np.ones_like(residual)
    return np.minimum(1.0, threshold / np.maximum(residual, 1e-300))


def _trilinear(lattice: Lattice, nodes: np.ndarray, points: np.ndarray):
    """The sparse ``(points, domain nodes)`` map from nodal values to their values at ``points``: Q1 on a lattice's
    axis-aligned cells is trilinear interpolation. (scikit-fem's own probes go through a tetrahedral search whose
    memory grows with points times cells.)"""
    import scipy.sparse
    position = np.clip((np.asarray(points) - lattice.low) / lattice.spacing, 0, np.array(lattice.shape) - 1)
    cell = np.minimum(np.floor(position).astype(np.int64), np.array(lattice.shape) - 2)
    t = position - cell
    column_of = -np.ones(int(np.prod(lattice.shape)), dtype=np.int64)
    column_of[nodes] = np.arange(len(nodes))
    nx, ny, _ = lattice.shape
    rows, columns, values = [], [], []
    for corner in np.ndindex(2, 2, 2):
        ijk = cell + np.array(corner)
        weight = np.prod(np.where(np.array(corner) == 1, t, 1.0 - t), axis=1)
        column = column_of[ijk[:, 0] + nx * (ijk[:, 1] + ny * ijk[:, 2])]
        if np.any(column[weight > 0] < 0):
            raise ValueError("a surface point lies in a cell outside the separation's domain")
        rows.append(np.arange(len(points)))
        columns.append(np.maximum(column, 0))
        values.append(np.where(column >= 0, weight, 0.0))
    return scipy.sparse.csr_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(columns))),
                                   shape=(len(points), len(nodes)))


def _normal_stress(stress6: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """``n.s.n`` for ``(N, 6)`` tensors (xx, yy, zz, yz, zx, xy) and unit ``normals`` (N, 3)."""
    x, y, z = normals.T
    xx, yy, zz, yz, zx, xy = stress6.T
    return xx * x * x + yy * y * y + zz * z * z + 2 * (yz * y * z + zx * z * x + xy * x * y)


def smooth_extension(values: np.ndarray, known: np.ndarray, shape: tuple[int, int, int], reach: int = 1) -> np.ndarray:
    """``values`` (nodes, C) on a lattice of ``shape``, with the nodes outside ``known`` within ``reach`` nodes
    of a known one replaced by the extension whose second differences are least (exact for linear fields), the
    rest by the nearest known value. A model masked outside its body (zero there) would otherwise put a jump
    into the cells the surface cuts."""
    import scipy.sparse
    import scipy.sparse.linalg
    from scipy.ndimage import binary_dilation

    from ..io.cells import fill_from_nearest
    nx, ny, nz = shape
    known = np.asarray(known, dtype=bool).reshape(nz, ny, nx)
    grid = fill_from_nearest(np.asarray(values, dtype=np.float64).reshape(nz, ny, nx, -1), known)
    solved = binary_dilation(known, np.ones((3, 3, 3), dtype=bool), iterations=reach) & ~known
    if not solved.any():
        return grid.reshape(len(values), -1)
    unknown = -np.ones(known.shape, dtype=np.int64)
    unknown[solved] = np.arange(int(solved.sum()))
    usable = known | solved
    rows, columns, coefficients, targets = [], [], [], []

    def add_stencil(weights, slices, weight):
        # One row per lattice position where every node of the stencil is usable and one at least unknown.
        index = [unknown[s] for s in slices]
        valid = np.all([usable[s] for s in slices], axis=0) & np.any([i >= 0 for i in index], axis=0)
        count = int(valid.sum())
        start = sum(len(t) for t in targets)
        row = start + np.arange(count)
        target = np.zeros((count, grid.shape[-1]))
        for w, s, i in zip(weights, slices, index):
            free, fixed = i[valid] >= 0, i[valid] < 0
            rows.append(row[free])
            columns.append(i[valid][free])
            coefficients.append(np.full(int(free.sum()), weight * w))
            target[fixed] -= weight * w * grid[s][valid][fixed]
        targets.append(target)

    for axis in range(3):
        n = known.shape[axis]

        def cut(a, b, axis=axis, n=n):
            return tuple(slice(a, n + b if b else None) if k == axis else slice(None) for k in range(3))
        if n >= 3:
            add_stencil((1.0, -2.0, 1.0), (cut(0, -2), cut(1, -1), cut(2, 0)), 1.0)
        add_stencil((1.0, -1.0), (cut(0, -1), cut(1, 0)), 1e-2)
    target = np.concatenate(targets)
    operator = scipy.sparse.csr_matrix((np.concatenate(coefficients), (np.concatenate(rows), np.concatenate(columns))),
                                       shape=(len(target), int(solved.sum())))
    normal = (operator.T @ operator).tocsc()
    grid[solved] = scipy.sparse.linalg.spsolve(normal, operator.T @ target).reshape(int(solved.sum()), -1)
    return grid.reshape(len(values), -1)
