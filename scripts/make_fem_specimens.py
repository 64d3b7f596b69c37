"""Solve and ship the FEM specimens of scenes/data/ (mesh .npz files read by `specimen` shapes).

The NeST paper's real epoxy specimens without a closed-form field: a triangular
prism under compression plus shear, a disk with a square hole under oblique
diametral compression, and an L bracket. Surfaces are built with trimesh, meshed
with gmsh (the optional GPL extra: pip install 'mi_nest[gmsh]'; only this
generator needs it) and solved with mi_nest.fem (epoxy E = 3 GPa, nu = 0.37).

    python scripts/make_fem_specimens.py
"""
import math
from pathlib import Path

import numpy as np
import trimesh

from mi_nest.fem import (Box, Fixture, Material, NearestNode, Plane, SolverConfig, Sphere, SurfaceForce,
                         mesh_surface, solve)

DATA = Path(__file__).resolve().parents[1] / "scenes" / "data"
EPOXY = Material(youngs_modulus=3000.0, poisson_ratio=0.37)
THICKNESS = 10.0


def extruded(polygon, triangles):
    """Closed prism of the 2D ``polygon`` (its ``triangles``) between z = -T/2 and T/2."""
    mesh = trimesh.creation.extrude_triangulation(np.asarray(polygon, float), np.asarray(triangles), THICKNESS)
    mesh.apply_translation((0.0, 0.0, -THICKNESS / 2))
    return mesh


def prism():
    """Triangle of side 40 (base on y = 0) with its apex flattened at y = 30 for a loading platen."""
    half, apex = 20.0, 20.0 * math.sqrt(3.0)
    top = 30.0
    shoulder = half * (1 - top / apex)
    polygon = [(-half, 0.0), (half, 0.0), (shoulder, top), (-shoulder, top)]
    surface = extruded(polygon, [[0, 1, 2], [0, 2, 3]])
    loads = [SurfaceForce("platen", Plane((0.0, top, 0.0), (0.0, 1.0, 0.0)), (250.0, -1000.0, 0.0))]
    fixtures = [Fixture("base", Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)))]
    return surface, loads, fixtures


def square_hole_disk(sections=128):
    """Disk of diameter 40 with a central 12 mm square hole, squeezed along 30 degrees from y."""
    assert sections % 8 == 0
    angle = np.arange(sections) * 2 * np.pi / sections + np.pi / 4
    direction = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    inner = 6.0 * direction / np.abs(direction).max(axis=1, keepdims=True)
    outer = 20.0 * direction
    polygon = np.concatenate([inner, outer])
    i = np.arange(sections)
    j = (i + 1) % sections
    triangles = np.concatenate([np.c_[i, sections + i, sections + j], np.c_[i, sections + j, j]])
    surface = extruded(polygon, triangles)
    load_axis = np.array([math.sin(math.radians(30.0)), math.cos(math.radians(30.0)), 0.0])
    loads = [SurfaceForce(f"pole {k}", Sphere(tuple(sign * 20.0 * load_axis), 2.5), tuple(-sign * 800.0 * load_axis))
             for k, sign in enumerate((1.0, -1.0))]
    # The loads balance: three point supports only remove the rigid-body motions.
    across = np.array([load_axis[1], -load_axis[0], 0.0])
    fixtures = [Fixture("pin", NearestNode(tuple(20.0 * across + (0, 0, -THICKNESS / 2)))),
                Fixture("slide", NearestNode(tuple(-20.0 * across + (0, 0, -THICKNESS / 2))), ("y", "z")),
                Fixture("rest", NearestNode((0.0, 20.0, -THICKNESS / 2)), ("z",))]
    return surface, loads, fixtures


def bracket():
    """L bracket: a 60 x 10 mm arm (along x) on a 10 x 50 mm post, clamped at the post's top."""
    polygon = [(0.0, 0.0), (60.0, 0.0), (60.0, 10.0), (10.0, 10.0), (10.0, 50.0), (0.0, 50.0)]
    surface = extruded(polygon, [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]])
    loads = [SurfaceForce("tip", Plane((60.0, 0.0, 0.0), (1.0, 0.0, 0.0)), (0.0, -150.0, 0.0))]
    fixtures = [Fixture("clamp", Box((-1.0, 49.0, -THICKNESS), (11.0, 51.0, THICKNESS)))]
    return surface, loads, fixtures


SPECIMENS = {"prism": prism, "square_hole_disk": square_hole_disk, "bracket": bracket}
# AMG-preconditioned CG stalls on the slender bracket in bending; P1 keeps it small enough for LU.
SETTINGS = {"prism": (2, SolverConfig()), "square_hole_disk": (2, SolverConfig()),
            "bracket": (1, SolverConfig(method="direct"))}


def main(element_size=1.25):
    for name, build in SPECIMENS.items():
        surface, loads, fixtures = build()
        assert surface.is_watertight and surface.volume > 0, name
        order, solver = SETTINGS[name]
        result = solve(mesh_surface(surface, element_size), EPOXY, loads, fixtures, element_order=order, solver=solver)
        result.save(DATA / f"{name}.npz")
        print(f"{name}: {result.report.tets} tets, {result.report.nodes} nodes, "
              f"{sum(result.report.seconds.values()):.1f} s -> scenes/data/{name}.npz")


if __name__ == "__main__":
    main()
