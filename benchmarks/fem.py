"""FEM solve time: a disk under diametral compression, P1 or P2, AMG-preconditioned CG.

Meshes the disk (radius 20 mm, thickness 4 mm) at the element size that gives
about ``--tets`` tetrahedra, solves it (mi_nest.fem.solve) and prints tets,
dofs, CG iterations and the time of each phase (mesh, assemble = dofs + loads +
stiffness, solve = AMG setup + CG, recover = reactions + nodal stress), plus the
centre stress difference against Frocht's 8P/(pi D t) as a sanity check.

    python benchmarks/fem.py                 # ~50k P1 tets
    python benchmarks/fem.py --tets 200000   # larger
    python benchmarks/fem.py --order 2 --tets 20000
"""
from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from mi_nest.fem import CylinderGeometry, Material, SolverConfig, solve

RADIUS, THICKNESS, LOAD = 20.0, 4.0, 1000.0


def element_size_for(tets):
    """Rings of 6k nodes make 6 (R/h)^2 triangles; t/h layers of prisms, 3 tets each: 18 R^2 t / h^3 tets."""
    return (18.0 * RADIUS ** 2 * THICKNESS / tets) ** (1.0 / 3.0)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tets", type=int, default=50_000, help="target number of tetrahedra (default 50000)")
    parser.add_argument("--order", type=int, choices=(1, 2), default=1, help="element order (default 1)")
    parser.add_argument("--method", choices=("auto", "amg", "direct"), default="amg")
    parser.add_argument("--recovery", choices=("l2", "average"), default="l2")
    args = parser.parse_args()

    h = element_size_for(args.tets)
    start = time.perf_counter()
    mesh = CylinderGeometry(RADIUS, THICKNESS, element_size=h).mesh()
    mesh_seconds = time.perf_counter() - start
    patch = 1.1 * h
    loads = [{"type": "force", "name": name, "force": [0.0, -sign * LOAD, 0.0],
              "where": {"type": "box", "min": [-patch, sign * RADIUS - 1.0, -THICKNESS],
                        "max": [patch, sign * RADIUS + 1.0, THICKNESS]}}
             for name, sign in (("top", 1.0), ("bottom", -1.0))]
    fixtures = [{"name": "pin", "where": {"type": "point", "point": [-RADIUS, 0.0, -THICKNESS / 2]}},
                {"name": "slide", "where": {"type": "point", "point": [RADIUS, 0.0, -THICKNESS / 2]},
                 "components": ["y", "z"]},
                {"name": "rest", "where": {"type": "point", "point": [0.0, RADIUS / 2, -THICKNESS / 2]},
                 "components": ["z"]}]
    start = time.perf_counter()
    result = solve(mesh, Material(2500.0, 0.36), loads, fixtures, element_order=args.order,
                   solver=SolverConfig(method=args.method, recovery=args.recovery))
    total = time.perf_counter() - start

    report = result.report
    centre = result.field.sample(np.array([[0.0, 0.0, 0.0]]))[0]
    frocht = 8 * LOAD / (math.pi * 2 * RADIUS * THICKNESS)
    print(f"cores {os.cpu_count()}, element size {h:.3f} mm")
    print(f"tets {report.tets}, nodes {report.nodes}, P{report.element_order} dofs {report.dofs}, "
          f"solver {report.solver} ({report.iterations} iterations, residual {report.residual:.1e})")
    print(f"time: mesh {mesh_seconds:.2f} s, " + ", ".join(f"{k} {v:.2f} s" for k, v in report.seconds.items())
          + f", solve() total {total:.2f} s")
    print(f"centre s_x - s_y {centre[0] - centre[1]:.3f} MPa vs Frocht {frocht:.3f} MPa "
          f"({100 * ((centre[0] - centre[1]) / frocht - 1):+.2f}%)")


if __name__ == "__main__":
    main()
