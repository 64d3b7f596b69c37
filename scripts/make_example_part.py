"""Regenerate scenes/examples/block_with_hole.msh, the part of docs/specimens.md's "Your own part, end to end".

An epoxy block 30 x 30 mm (x, y) and 8 mm thick (z, centred on z = 0) with a 10 mm hole through it along z,
as first-order tetrahedra in a gmsh 2.2 ASCII file with three named surfaces (gmsh physical surfaces):
``base`` (y = -15), ``top`` (y = 15) and ``hole`` (the bore), and the volume ``block``. Made without
gmsh (GPL): the cross-section is rings of nodes from the hole's circle out to the square, stitched into
triangles and extruded along z by ``mi_nest.fem.meshing.extrude``; scikit-fem finds the boundary faces.
Deterministic: the same file on every run.

    python scripts/make_example_part.py
"""
from pathlib import Path

import meshio
import numpy as np
from skfem import MeshTet

from mi_nest.fem.meshing import extrude
from mi_nest.io.cells import signed_volumes

EXAMPLES = Path(__file__).resolve().parents[1] / "scenes" / "examples"
NAME = "block_with_hole.msh"
SIDE = 30.0             # mm, the block's width (x) and height (y)
HOLE_RADIUS = 5.0
THICKNESS = 8.0
SECTIONS = 32           # nodes around the hole and the square; a multiple of 8 puts the square's corners on them
RINGS = 4               # element layers from the hole out to the square
LAYERS = 4              # element layers through the thickness
# gmsh physical groups: name -> (tag, dimension).
GROUPS = {"base": (1, 2), "top": (2, 2), "hole": (3, 2), "block": (4, 3)}


def square(count, half):
    """``count`` points evenly spaced along the square of half-side ``half``, counter-clockwise from its
    (+, +) corner, so that corners fall on every ``count / 4``-th point as the hole's 45-degree points do."""
    per_side = count // 4
    corners = half * np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    steps = np.arange(per_side)[:, None] / per_side
    return np.concatenate([a + steps * (b - a) for a, b in zip(corners, np.roll(corners, -1, axis=0))])


def cross_section():
    """``(points (P, 2), triangles (T, 3))`` of the square with its hole: rings between circle and square,
    graded towards the hole, where the stress concentrates."""
    angle = 2.0 * np.pi * np.arange(SECTIONS) / SECTIONS + np.pi / 4
    inner = HOLE_RADIUS * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    outer = square(SECTIONS, SIDE / 2)
    share = (np.arange(RINGS + 1) / RINGS) ** 1.5
    points = np.concatenate([(1.0 - s) * inner + s * outer for s in share])
    ring, position = np.meshgrid(np.arange(RINGS), np.arange(SECTIONS), indexing="ij")
    a = ring * SECTIONS + position
    b = ring * SECTIONS + (position + 1) % SECTIONS
    c, d = b + SECTIONS, a + SECTIONS
    triangles = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return points, triangles


def boundary_triangles(mesh, picked):
    """The boundary faces of ``mesh`` whose corners all satisfy ``picked(points (3, K)) -> bool (K,)``,
    ordered (F, 3) so that their normals point out of the part, as gmsh writes them."""
    facets = mesh.boundary_facets()
    corners = mesh.p[:, mesh.facets[:, facets]]                        # (3, 3 corners, F)
    facets = facets[np.all(picked(corners.reshape(3, -1)).reshape(3, -1), axis=0)]
    triangles = mesh.facets[:, facets].T
    first, second, third = (mesh.p[:, triangles[:, k]].T for k in range(3))
    tet = mesh.t[:, mesh.f2t[0, facets]]
    inward = mesh.p[:, tet].mean(axis=1).T - first                     # towards the owning tetrahedron's centroid
    flip = np.einsum("ij,ij->i", np.cross(second - first, third - first), inward) > 0
    triangles[flip] = triangles[flip][:, [0, 2, 1]]
    return triangles


def block_with_hole() -> meshio.Mesh:
    points, triangles = cross_section()
    nodes, tets = extrude(points, triangles, THICKNESS, LAYERS)
    nodes[:, 2] -= THICKNESS / 2
    # Rounded to a nanometre (and -0 to 0), so that the last bits of a platform's cos and sin (x = 3e-16 where
    # the hole meets the y axis) never reach the file.
    nodes = np.round(nodes, 9) + 0.0
    negative = signed_volumes(nodes, tets) < 0                         # gmsh orders every tetrahedron positively
    tets[negative] = tets[negative][:, [0, 1, 3, 2]]
    mesh = MeshTet(np.ascontiguousarray(nodes.T), np.ascontiguousarray(tets.T))
    tolerance = 1e-9 * SIDE
    faces = {"base": boundary_triangles(mesh, lambda p: np.abs(p[1] + SIDE / 2) < tolerance),
             "top": boundary_triangles(mesh, lambda p: np.abs(p[1] - SIDE / 2) < tolerance),
             "hole": boundary_triangles(mesh, lambda p: np.abs(np.hypot(p[0], p[1]) - HOLE_RADIUS) < tolerance)}
    tags = np.concatenate([np.full(len(faces[name]), GROUPS[name][0]) for name in faces])
    volume = np.full(len(tets), GROUPS["block"][0])
    return meshio.Mesh(nodes, [("tetra", tets), ("triangle", np.concatenate(list(faces.values())))],
                       cell_data={"gmsh:physical": [volume, tags], "gmsh:geometrical": [volume, tags]},
                       field_data={name: np.array(tag_dimension) for name, tag_dimension in GROUPS.items()})


def main(folder: Path = EXAMPLES) -> Path:
    path = Path(folder) / NAME
    mesh = block_with_hole()
    meshio.write(path, mesh, file_format="gmsh22", binary=False, float_fmt=".12g")   # the nanometre grid, exactly
    faces = mesh.cells[1].data
    groups = ", ".join(f"{name} ({np.sum(mesh.cell_data['gmsh:physical'][1] == tag)} triangles)"
                       for name, (tag, dimension) in GROUPS.items() if dimension == 2)
    print(f"{path}: {len(mesh.points)} nodes, {len(mesh.cells[0].data)} tetrahedra, {len(faces)} named faces: "
          f"{groups}; {path.stat().st_size // 1024} KiB")
    return path


if __name__ == "__main__":
    main()
