"""Elastic completion: how close a reconstruction of the disk comes to the elastic fields the part could hold.

A P2 tetrahedral basis of the disk (``CylinderGeometry``), loaded by self-equilibrated forces at its boundary dofs:
each load gives a displacement (one sparse LU of the stiffness), and the deviator of its stress at the quadrature
points. LSQR fits those loads to the true deviator (the basis' floor: how close an elastic field of this mesh comes
to the truth) and to the reconstruction's; errors are dx-weighted at the same points, off-diagonals counted twice.
If the fit of the reconstruction came near the floor, projecting onto elastic fields would mend the wrong branch.

``--far D`` fits only the points farther than D mm from the contacts (the two peaks of the true stress, 10 mm
apart or more): does elasticity carry a far field that the data fix into the contacts a coarse grid cannot hold?
``--sparse-rounds N`` then reweights the loads N times towards a few loaded nodes (group L1 by iterative
reweighting), as contacts load a part.

    .venv/bin/python experiments/elastic_completion.py RESULT --element-size 1.5 --poisson 0.35 --iterations 400
    .venv/bin/python experiments/elastic_completion.py RESULT --element-size 2 --iterations 150 --far 4 --sparse-rounds 3

RESULT is a ``mi-nest reconstruct`` output of a simulated disk dataset. Prints the numbers and the CPU.
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import common

import mi_nest  # noqa: F401  (sets the variant)
from mi_nest.fem.meshing import CylinderGeometry
from mi_nest.fem.solve import Material, scalar_basis, shape_gradients, stiffness
from mi_nest.fem.loads import rigid_body_modes
from mi_nest.fields.base import sample
from mi_nest.physics.tensors import deviatoric_part, tensor_norm
from mi_nest.reconstruct import Reconstruction
from mi_nest.scene import specimen_shapes

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from reconstruction import cpu_name  # noqa: E402

W6 = np.array([1, 1, 1, 2, 2, 2.0])        # the weights of tensor_norm: LSQR minimises the same norm
NEAR = 4.0              # mm from a contact: the region the errors are also given for
CONTACTS_APART = 10.0   # mm at least between the two contacts
SPARSE_FLOOR = 1e-4     # of the largest node's load: keeps every node's load free to grow back


def disk_geometry(scene, element_size):
    """The scene's one specimen as a z-axis cylinder about its bounding box centre; refused for another part."""
    shapes = specimen_shapes(scene)
    if len(shapes) != 1:
        raise SystemExit(f"{len(shapes)} specimens in the result's scene: elastic completion takes one disk")
    box = shapes[0].bbox()
    low, high = np.array(box.min, dtype=float), np.array(box.max, dtype=float)
    width, depth, height = high - low
    if not np.isclose(width, depth, rtol=1e-3):
        raise SystemExit(f"the specimen is {width:.3g} x {depth:.3g} mm across: elastic completion takes a disk "
                         "(a cylinder about z)")
    return CylinderGeometry(radius=width / 2, height=height, center=tuple((low + high) / 2),
                            element_size=element_size)


def deviator_operator(basis):
    """Sparse (6 M, 3 N): 2 mu dev eps (mu = 1) at the M = e*q quadrature points, rows component-major."""
    G = shape_gradients(basis)                      # (e, q, a, 3)
    e, q, a, _ = G.shape
    M = e * q
    dofs = np.repeat(basis.element_dofs.T[:, None, :], q, axis=1).reshape(M, a)   # (M, a)
    G = G.reshape(M, a, 3)
    rows, cols, vals = [], [], []

    def add(comp, c, d, w):
        rows.append(np.repeat(comp * M + np.arange(M), a))
        cols.append((3 * dofs + c).ravel())
        vals.append((w * G[:, :, d]).ravel())
    for i in range(3):                              # dev_ii = 2 (e_ii - tr/3)
        for k in range(3):
            add(i, k, k, 2 * ((1.0 if k == i else 0.0) - 1 / 3))
    for comp, (i, j) in zip((3, 4, 5), ((1, 2), (2, 0), (0, 1))):   # 3D-TSV order yz zx xy
        add(comp, i, j, 1.0)
        add(comp, j, i, 1.0)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(6 * M, 3 * basis.N))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("result", type=Path, help="a mi-nest reconstruct output directory of a simulated disk")
    parser.add_argument("--element-size", type=float, default=1.5, help="tetrahedron size in mm")
    parser.add_argument("--poisson", type=float, default=0.35, help="Poisson's ratio of the basis")
    parser.add_argument("--iterations", type=int, default=400, help="LSQR iterations per fit")
    parser.add_argument("--far", type=float, default=0.0, help="fit only the points this far (mm) from the contacts")
    parser.add_argument("--sparse-rounds", type=int, default=0, help="reweightings of the loads towards few nodes")
    args = parser.parse_args()
    print(f"CPU: {cpu_name()}")
    try:
        result = Reconstruction.load(args.result)
    except FileNotFoundError as error:
        raise SystemExit(str(error)) from None
    h, nu, iters = args.element_size, args.poisson, args.iterations
    _, scene, truth = common.simulated_from(result)
    t = time.perf_counter()
    mesh = disk_geometry(scene, h).mesh()
    basis = scalar_basis(mesh, 2)
    K = stiffness(basis, Material(2 * (1 + nu), nu)).tocsc()
    points = basis.mapping.F(basis.X).reshape(3, -1).T          # (M, 3), element-major then q
    dx = basis.dx.reshape(-1)
    S = deviator_operator(basis)
    bdofs = basis.get_dofs().all()
    bvec = (3 * bdofs[:, None] + np.arange(3)).ravel()
    R = rigid_body_modes(basis)[bvec]
    Rq, _ = np.linalg.qr(R)
    lu = spla.splu((K + 1e-8 * K.diagonal().mean() * sp.identity(K.shape[0])).tocsc(), permc_spec="MMD_AT_PLUS_A")
    print(f"h {h}: tets {mesh.nelements}, P2 nodes {basis.N}, boundary {len(bdofs)}, points {len(points)}, "
          f"setup {time.perf_counter() - t:.1f} s", flush=True)
    t6 = deviatoric_part(sample(truth, points))
    r6 = deviatoric_part(sample(result.field, points))
    true_norm = tensor_norm(t6)
    first = points[np.argmax(true_norm)]
    apart = np.linalg.norm(points - first, axis=1) >= CONTACTS_APART
    second = points[apart][np.argmax(true_norm[apart])]
    from_contacts = np.minimum(np.linalg.norm(points - first, axis=1), np.linalg.norm(points - second, axis=1))
    near = from_contacts <= NEAR
    fitted = from_contacts > args.far
    w = np.sqrt(dx * fitted)[None] * np.sqrt(W6)[:, None]                 # (6, M)

    def distance(a6, b6, where=None):
        where = np.ones(len(dx), bool) if where is None else where
        return np.sqrt((dx[where] * tensor_norm(a6[where] - b6[where]) ** 2).sum() /
                       (dx[where] * true_norm[where] ** 2).sum())

    def errors(d6):
        return (f"error against the truth {distance(d6, t6):.4f} (within {NEAR:g} mm of the contacts "
                f"{distance(d6, t6, near):.4f}, beyond {distance(d6, t6, ~near):.4f})")

    def field_of(fb):
        fb = fb - Rq @ (Rq.T @ fb)
        f = np.zeros(K.shape[0])
        f[bvec] = fb
        return lu.solve(f)

    def adjoint(g):
        fb = lu.solve(g)[bvec]
        return fb - Rq @ (Rq.T @ fb)
    wf = w.ravel()
    print(f"fitted beyond {args.far:g} mm of the contacts at {first.round(1)} and {second.round(1)}: "
          f"{fitted.sum()} of {len(points)} points", flush=True)
    print(f"result's own {errors(r6)}", flush=True)
    for name, target in (("truth", t6), ("result", r6)):
        scale = np.ones(len(bvec))
        for reweighting in range(args.sparse_rounds + 1):
            t = time.perf_counter()
            # Loads f = scale * g: LSQR's least-norm g is then a least-|f| / scale load, the group L1's reweighting.
            A = spla.LinearOperator((S.shape[0], len(bvec)), matvec=lambda g: wf * (S @ field_of(scale * g)),
                                    rmatvec=lambda r: scale * adjoint(S.T @ (wf * r)))
            sol = spla.lsqr(A, wf * target.T.ravel(), iter_lim=iters, atol=1e-12, btol=1e-12)
            loads = scale * sol[0]
            d = (S @ field_of(loads)).reshape(6, -1).T
            per_node = np.linalg.norm(loads.reshape(-1, 3), axis=1)
            carrying = int(np.searchsorted(np.sort(per_node)[::-1].cumsum() / per_node.sum(), 0.9)) + 1
            print(f"{name}'s elastic fit (reweighting {reweighting}): {errors(d)}, misfit to its target where "
                  f"fitted {distance(d, target, fitted):.4f}, {carrying} nodes carry 90% of the load ({sol[2]} it, "
                  f"{time.perf_counter() - t:.0f} s)", flush=True)
            scale = np.repeat(np.sqrt(per_node / per_node.max() + SPARSE_FLOOR), 3)


if __name__ == "__main__":
    main()
