"""Isotropic linear elasticity on a tetrahedral mesh (scikit-fem) and nodal stress recovery.

Units: mm, N, MPa (Young's modulus in MPa, so stresses come out in MPa).
Each displacement component is a P1 (linear, 4-node) or P2 (quadratic,
10-node) Lagrange field on one scalar skfem basis; vector dof ``3 d + c`` is
component ``c`` of scalar dof ``d`` (the numbering of skfem's ``ElementVector``).
The stiffness matrix is skfem's ``linear_elasticity`` form, evaluated by a
vectorised kernel here (:func:`stiffness`; the tests compare the two).

Fixtures are eliminated symmetrically (rows and columns of prescribed dofs
replaced by a scaled identity) rather than condensed away, which keeps the
x-y-z blocks of every node intact so that smoothed-aggregation AMG can
aggregate whole nodes and use the six rigid-body modes as its near-null space
(what makes it converge in tens of CG iterations for elasticity). Small
systems go to SciPy's sparse LU instead.

The stress is constant (P1) or linear (P2) inside each tetrahedron and jumps
between them. :func:`nodal_stress` recovers one tensor per mesh vertex either
by L2 projection onto continuous P1 functions (``"l2"``, the default: the
P1 field closest to the element stresses in the mean-square sense, a global
solve with the mass matrix) or by the volume-weighted average of the mean
stress of the tetrahedra around each vertex (``"average"``, local and cheap).
"""
from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from ..fields.mesh import TetMeshStress
from ..io.mesh import save_mesh_stress
from ..io.tsv import BoundaryConditions
from ..physics.tensors import von_mises
from .config import FemError, number, parse_fields
from .loads import check_rigid_modes, constraints, load_vector, rigid_body_modes

if TYPE_CHECKING:
    from skfem import CellBasis, MeshTet

    from .loads import Fixture, Load

METHODS = ("auto", "amg", "direct")
RECOVERIES = ("l2", "average")
_VOIGT = ((0, 0), (1, 1), (2, 2), (1, 2), (2, 0), (0, 1))   # 3D-TSV order: xx yy zz yz zx xy


@dataclass(frozen=True)
class Material:
    """Isotropic linear-elastic material: Young's modulus (MPa) and Poisson's ratio."""
    youngs_modulus: float
    poisson_ratio: float

    def __post_init__(self):
        object.__setattr__(self, "youngs_modulus", number("youngs_modulus", self.youngs_modulus, positive=True))
        nu = number("poisson_ratio", self.poisson_ratio)
        if not -1.0 < nu < 0.5:
            raise FemError(f"'poisson_ratio' must lie in (-1, 0.5), got {self.poisson_ratio!r}")
        object.__setattr__(self, "poisson_ratio", nu)

    @property
    def lame(self) -> tuple[float, float]:
        """``(lambda, mu)`` in MPa."""
        E, nu = self.youngs_modulus, self.poisson_ratio
        return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


@dataclass(frozen=True)
class SolverConfig:
    """How to solve and post-process.

    ``method``: ``"amg"`` (CG preconditioned by smoothed-aggregation AMG),
    ``"direct"`` (sparse LU) or ``"auto"`` (direct below ``direct_below`` dofs).
    ``tolerance`` is the relative residual ||K u - f|| / ||f|| the iterative
    solve must reach. ``recovery`` picks the nodal stress recovery (module doc).
    """
    method: str = "auto"
    tolerance: float = 1e-10
    max_iterations: int = 500
    direct_below: int = 5000
    recovery: str = "l2"

    def __post_init__(self):
        if self.method not in METHODS:
            raise FemError(f"'method' must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.recovery not in RECOVERIES:
            raise FemError(f"'recovery' must be one of {', '.join(RECOVERIES)}, got {self.recovery!r}")
        object.__setattr__(self, "tolerance", number("tolerance", self.tolerance, positive=True))
        for name in ("max_iterations", "direct_below"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise FemError(f"'{name}' must be a non-negative integer, got {value!r}")


@dataclass
class SolveReport:
    """Sizes, solver statistics, timings (s) and force balance (N) of one solve."""
    tets: int
    nodes: int
    element_order: int
    dofs: int
    constrained_dofs: int
    solver: str
    iterations: int          # CG iterations (0 for the direct solver)
    residual: float          # ||A u - b|| / ||b|| of the system actually solved
    seconds: dict = field(default_factory=dict)
    applied: dict = field(default_factory=dict)      # load name -> total force (3,)
    reactions: dict = field(default_factory=dict)    # fixture name -> reaction force (3,)

    def summary(self) -> str:
        lines = [f"{self.tets} tets, {self.nodes} nodes, P{self.element_order}: {self.dofs} dofs "
                 f"({self.constrained_dofs} fixed)",
                 f"solver {self.solver}"
                 + (f" (CG + AMG): {self.iterations} iterations" if self.solver == "amg" else " (sparse LU)")
                 + f", relative residual {self.residual:.2e}",
                 "time " + ", ".join(f"{k} {v:.2f} s" for k, v in self.seconds.items())]
        lines += [f"load '{k}': force ({', '.join(f'{x:.4g}' for x in v)}) N" for k, v in self.applied.items()]
        lines += [f"fixture '{k}': reaction ({', '.join(f'{x:.4g}' for x in v)}) N"
                  for k, v in self.reactions.items()]
        return "\n".join(lines)


@dataclass
class FemResult:
    """Nodal stress (``field``), nodal displacement (N, 3) mm, the skfem mesh, the report and the boundary
    conditions at the mesh's vertices (node forces, fully fixed nodes), as 3D-TSV records them."""
    field: TetMeshStress
    displacement: np.ndarray
    mesh: object
    report: SolveReport
    boundary: BoundaryConditions

    def save(self, path: str | Path) -> None:
        """Write the stress and the boundary conditions as a mesh ``.npz``
        (:func:`mi_nest.io.mesh.save_mesh_stress`)."""
        save_mesh_stress(path, self.field.nodes, self.field.tets, self.field.stress, self.boundary)

    def summary(self) -> str:
        """The report plus where the stress and the displacement peak."""
        equivalent = von_mises(self.field.stress)
        peak = int(np.argmax(equivalent))
        moved = np.linalg.norm(self.displacement, axis=1)
        at = ", ".join(f"{v:.4g}" for v in self.field.nodes[peak])
        return (self.report.summary() + f"\nvon Mises stress up to {equivalent[peak]:.4g} MPa (node at {at}); "
                f"displacement up to {moved.max():.4g} mm")


def scalar_basis(mesh: MeshTet, order: int) -> CellBasis:
    """The scalar P1/P2 basis of one displacement component (vector dof of scalar dof d: 3 d + c).

    Quadrature of order 2 integrates the stiffness exactly for P1 and P2 (its
    integrand has degree 2 (order - 1)) and the mass matrix and load of the P1
    stress projection too; skfem's default for P2 (order 4, 11 points) would
    cost about three times as much for nothing.
    """
    from skfem import Basis, ElementTetP1, ElementTetP2
    if order not in (1, 2) or isinstance(order, bool):
        raise FemError(f"'element_order' must be 1 (linear tets) or 2 (quadratic tets), got {order!r}")
    return Basis(mesh, ElementTetP1() if order == 1 else ElementTetP2(), intorder=2)


def shape_gradients(basis: CellBasis) -> np.ndarray:
    """Gradients of the scalar shape functions: (elements, quadrature points, functions, 3)."""
    gradients = np.stack([basis.basis[a][0].grad for a in range(basis.Nbfun)])   # (a, i, element, q)
    return gradients.transpose(2, 3, 0, 1)


def stiffness(basis: CellBasis, material: Material, chunk: int = 8192) -> sp.csr_matrix:
    """Global stiffness matrix (CSR, 3 N x 3 N) of isotropic linear elasticity on the scalar ``basis``.

    The bilinear form of skfem's ``linear_elasticity``,
    ``2 mu eps(u):eps(v) + lambda tr eps(u) tr eps(v)``, evaluated for all
    shape-function pairs of a chunk of elements at once: with ``T[a,i,b,j] =
    sum_q w_q d_i phi_a d_j phi_b`` (one batched matrix product), the element
    matrix for test (a, i) and trial (b, j) is
    ``lambda T[a,i,b,j] + mu T[a,j,b,i] + mu delta_ij sum_k T[a,k,b,k]``.
    (skfem's generic form loops over the 30 x 30 pairs of a P2 element in Python,
    about twenty times slower.)
    """
    lam, mu = material.lame
    count = basis.Nbfun
    gradients = shape_gradients(basis)                          # (e, q, a, i)
    weights = basis.dx                                          # (e, q)
    dofs = basis.element_dofs.T                                 # (e, a)
    vector_dofs = (3 * dofs[:, :, None] + np.arange(3)).reshape(len(dofs), -1)   # (e, (a, i))
    size = 3 * count
    blocks = []
    for start in range(0, len(dofs), chunk):
        part = slice(start, start + chunk)
        g = gradients[part].reshape(-1, weights.shape[1], size)                  # (e, q, (a, i))
        T = np.matmul(np.swapaxes(g * weights[part, :, None], 1, 2), g).reshape(-1, count, 3, count, 3)
        trace = np.einsum("eakbk->eab", T)
        local = (lam * T + mu * T.transpose(0, 1, 4, 3, 2)
                 + mu * trace[:, :, None, :, None] * np.eye(3)[None, None, :, None, :])
        rows = np.repeat(vector_dofs[part], size, axis=1).ravel()
        cols = np.tile(vector_dofs[part], (1, size)).ravel()
        blocks.append(sp.csr_matrix((local.reshape(-1), (rows, cols)), shape=(3 * basis.N, 3 * basis.N)))
    return sum(blocks[1:], blocks[0]).tocsr()


def _eliminate(K, f, dofs, values):
    """Symmetric system with ``u[dofs] = values``: those rows/columns become ``scale * I``."""
    u0 = np.zeros(K.shape[0])
    u0[dofs] = values
    rhs = f - K @ u0
    free = np.ones(K.shape[0])
    free[dofs] = 0.0
    scale = K.diagonal().mean()    # keeps the identity rows in the range of the others
    # Multiplying by diagonals (instead of slicing) keeps the sparsity pattern and its 3x3 blocks.
    A = (sp.diags(free) @ K @ sp.diags(free) + sp.diags(scale * (1.0 - free))).tocsr()
    rhs[dofs] = scale * values
    return A, rhs


def _solve_direct(A, b):
    from scipy.sparse.linalg import splu
    try:
        # MMD on A^T + A suits symmetric matrices far better than the default COLAMD.
        return splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A").solve(b), 0
    except RuntimeError as error:
        raise FemError(f"the stiffness matrix is singular ({error}): the fixtures do not hold the model, "
                       f"or parts of the mesh are disconnected") from None


def _solve_amg(A, b, modes, config):
    import pyamg
    # Whole-node (3x3 block) aggregation with the rigid modes as candidates; stop at a few
    # thousand coarse dofs and factorise those (pyamg's default dense pseudo-inverse of a
    # coarse level that size would take longer than the whole cycle).
    ml = pyamg.smoothed_aggregation_solver(A.tobsr(blocksize=(3, 3)), B=modes, symmetry="symmetric",
                                           improve_candidates=None, max_coarse=500, coarse_solver="splu")
    residuals = []
    u = ml.solve(b, tol=config.tolerance, accel="cg", maxiter=config.max_iterations, residuals=residuals)
    return u, len(residuals) - 1


def solve_linear_system(A: sp.csr_matrix, b: np.ndarray, modes: np.ndarray, config: SolverConfig
                        ) -> tuple[np.ndarray, str, int]:
    """``(u, method, iterations)`` with the method ``config`` asks for."""
    method = config.method
    if method == "auto":
        method = "direct" if A.shape[0] < config.direct_below else "amg"
    if method == "direct":
        u, iterations = _solve_direct(A, b)
    else:
        u, iterations = _solve_amg(A, b, modes, config)
    return u, method, iterations


def element_stress(basis: CellBasis, u: np.ndarray, material: Material) -> np.ndarray:
    """Stress at the quadrature points: (6, elements, points), 3D-TSV order."""
    lam, mu = material.lame
    nodal = u.reshape(-1, 3)[basis.element_dofs.T]              # (e, a, component)
    grad = np.einsum("eqaj,eai->ijeq", shape_gradients(basis), nodal)   # grad[i, j] = d u_i / d x_j
    strain = 0.5 * (grad + np.swapaxes(grad, 0, 1))
    trace = strain[0, 0] + strain[1, 1] + strain[2, 2]
    return np.stack([2 * mu * strain[i, j] + (lam * trace if i == j else 0.0) for i, j in _VOIGT])


def nodal_stress(basis: CellBasis, stress: np.ndarray, recovery: str = "l2") -> np.ndarray:
    """(vertices, 6) nodal stress from quadrature-point values (see the module doc)."""
    from pyamg.krylov import cg
    from skfem import BilinearForm, ElementTetP1, LinearForm
    scalar = basis if basis.elem.maxdeg == 1 else basis.with_element(ElementTetP1())   # same quadrature
    if recovery == "average":
        volume = scalar.dx.sum(axis=1)                        # (elements,)
        mean = (stress * scalar.dx).sum(axis=2) / volume      # (6, elements)
        corners = basis.mesh.t                                # (4, elements)
        total = np.zeros((6, basis.mesh.nvertices))
        weight = np.zeros(basis.mesh.nvertices)
        for corner in corners:
            np.add.at(total.T, corner, (mean * volume).T)
            np.add.at(weight, corner, volume)
        return (total / weight).T
    mass = BilinearForm(lambda u, v, w: u * v).assemble(scalar).tocsr()
    jacobi = sp.diags(1.0 / mass.diagonal())
    result = np.empty((basis.mesh.nvertices, 6))
    for component in range(6):
        rhs = LinearForm(lambda v, w: w["s"] * v).assemble(scalar, s=stress[component])
        # The mass matrix is well conditioned (bounded independently of the mesh size for
        # shape-regular meshes), so Jacobi-preconditioned CG converges in a few dozen steps.
        values, info = cg(mass, rhs, tol=1e-12, M=jacobi, maxiter=1000)
        if info != 0:
            raise FemError(f"stress recovery (L2 projection) did not converge (cg info {info})")
        result[:, component] = values
    return result


def solve(mesh: MeshTet, material: Material | Mapping, loads: Sequence[Load | Mapping],
          fixtures: Sequence[Fixture | Mapping], element_order: int = 1,
          solver: SolverConfig = SolverConfig()) -> FemResult:
    """Solve the elasticity problem; returns a :class:`FemResult`.

    ``mesh`` is a ``skfem.MeshTet``; ``loads`` and ``fixtures`` are lists of
    :mod:`mi_nest.fem.loads` specs (or their dict forms).
    """
    from .loads import parse_fixture, parse_load
    loads = [parse_load(load, i) for i, load in enumerate(loads)]
    fixtures = [parse_fixture(fixture, i) for i, fixture in enumerate(fixtures)]
    if not isinstance(material, Material):
        material = parse_fields(Material, material, "material")
    clock = time.perf_counter()
    seconds = {}
    basis = scalar_basis(mesh, element_order)
    fixed = constraints(basis, fixtures)
    check_rigid_modes(basis, fixed, fixtures)
    f, applied = load_vector(basis, loads)
    K = stiffness(basis, material)
    seconds["assemble"] = time.perf_counter() - clock

    clock = time.perf_counter()
    A, b = _eliminate(K, f, fixed.dofs, fixed.values)
    u, method, iterations = solve_linear_system(A, b, rigid_body_modes(basis), solver)
    norm_b = np.linalg.norm(b) or 1.0
    residual = float(np.linalg.norm(A @ u - b) / norm_b)
    seconds["solve"] = time.perf_counter() - clock
    if not np.all(np.isfinite(u)):
        raise FemError("the solution is not finite: the stiffness matrix is singular (insufficient fixtures "
                       "or a disconnected mesh)")
    if residual > 10 * solver.tolerance:
        # Bodies that nothing holds were refused before the solve (check_rigid_modes, per body).
        raise FemError((f"AMG-preconditioned CG did not converge: relative residual {residual:.2e} after "
                        f"{iterations} iterations (tolerance {solver.tolerance:g}): raise max_iterations or use "
                        "method = 'direct' for small models") if method == "amg" else
                       (f"the sparse LU solution does not solve the system: relative residual {residual:.2e} "
                        f"(tolerance {solver.tolerance:g}): the stiffness matrix is singular, so the model moves "
                        "without straining somewhere; parts of the mesh joined only at a node or an edge turn "
                        "about it, so join them through faces, or fix each part"))

    clock = time.perf_counter()
    reaction = K @ u - f
    reactions = {name: np.array([reaction[dofs[dofs % 3 == c]].sum() for c in range(3)])  # dof 3 d + c
                 for name, dofs in fixed.by_fixture.items()}
    stress = nodal_stress(basis, element_stress(basis, u, material), solver.recovery)
    displacement = u.reshape(-1, 3)[basis.nodal_dofs[0]]
    result_field = TetMeshStress.from_cells(mesh.p.T, mesh.t.T, stress)
    seconds["recover"] = time.perf_counter() - clock

    report = SolveReport(tets=mesh.nelements, nodes=mesh.nvertices, element_order=element_order,
                         dofs=3 * basis.N, constrained_dofs=len(fixed.dofs), solver=method,
                         iterations=iterations, residual=residual, seconds=seconds,
                         applied=applied, reactions=reactions)
    return FemResult(result_field, displacement, mesh, report, vertex_conditions(basis, f, fixed.dofs))


def vertex_conditions(basis: CellBasis, forces: np.ndarray, fixed_dofs: np.ndarray) -> BoundaryConditions:
    """The load vector as forces on the mesh's vertices (a P2 edge node's force shared by its edge's two ends:
    the total force and its balance are kept) and the vertices whose three components are fixed."""
    nodal = forces.reshape(-1, 3)
    at_vertices = nodal[basis.nodal_dofs[0]].copy()
    if basis.edge_dofs.size:
        edges = basis.mesh.edges
        for end in edges:
            np.add.at(at_vertices, end, 0.5 * nodal[basis.edge_dofs[0]])
    size = np.abs(at_vertices).max(axis=1)
    # The assembly leaves round-off (1e-15 of the largest force) on vertices no load reaches.
    loaded = np.flatnonzero(size > 1e-12 * max(size.max(), 1e-300))
    fixed_components = np.zeros(3 * basis.N, dtype=bool)
    fixed_components[fixed_dofs] = True
    fixed = np.flatnonzero(fixed_components.reshape(-1, 3)[basis.nodal_dofs[0]].all(axis=1))
    return BoundaryConditions(loaded, at_vertices[loaded], fixed)
