"""The mean stress separated by equilibrium (issue 35): accuracy on exact fields, reconstructions, and speed.

1. Exact equilibrium fields (a uniaxial bar, pure bending, Lame's tube under internal pressure, Frocht's disk over
   4 mm contacts, Boussinesq's half-space) and the kitten's FEM field: only their deviator is given; the separated
   mean stress is compared with their own, at the lattice's nodes inside the part, everywhere and away from the
   loads (a tenth of the part's size from the loaded surface, or from the point load), per the RMS stress there.
2. Reconstructions (the accuracy suite's grid results, :data:`RECONSTRUCTIONS`, where they exist): the full
   tensor's error beside the deviator's.
3. Speed: a 64^3 lattice filled by a cube, in a child process (its peak memory is the child's).

    python benchmarks/separation.py [--quick]

Writes ``experiments/results/separation.csv`` (``--quick``: ``experiments/out/separation_quick.csv``; ``--csv``
elsewhere); prints the table, the CPU and the seconds.
"""
from __future__ import annotations

import argparse
import csv
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mitsuba as mi
import numpy as np
from scipy.spatial import cKDTree

import mi_nest
from mi_nest.fields.base import sample
from mi_nest.views import open_source
from mi_nest.scene import specimen_media
from mi_nest.separation import separate
from mi_nest.separation.report import against_truth, errors, inside_nodes
from reconstruction import cpu_name

HERE = Path(__file__).resolve().parents[1]
SUITE = HERE / "experiments" / "out" / "accuracy_suite" / "accuracy_suite"


def bar(shape=(30.0, 5.0, 5.0), **stress):
    """A box of uniform stress, its faces loaded where that stress has traction."""
    cube = {"type": "cube", "to_world": mi.ScalarTransform4f().scale([0.5 * s for s in shape]),
            "interior": {"type": "stress", "model": "uniform", "fringe_value": 10.6, **stress}}
    return mi.load_dict({"type": "scene", "embree_use_robust_intersections": True, "part": cube})


# name, the scene, the points whose neighbourhood is a point load (None: the loaded surface found)
CASES = [
    ("uniaxial bar", lambda: bar(xx=6.0), None),
    ("pure bending", lambda: mi_nest.load_scene("beam_bending"), None),
    ("Lame tube, internal pressure", lambda: mi_nest.load_scene("lame_cylinder"), None),
    ("Frocht disk, 4 mm contacts", lambda: mi_nest.load_scene("disk_compression", contact_width="4", load="100"),
     None),
    ("Boussinesq half-space", lambda: mi_nest.load_scene("boussinesq"), [(0.0, 0.0, 0.0)]),
    ("kitten FEM (3D-TSV)", lambda: mi_nest.load_scene("kitten"), None),
]


# The accuracy suite's grid results (benchmarks/accuracy_suite.py), where they exist, with the loaded regions a
# user gives where the scene does not know them (the bracket's file records no loads: its tip face and the clamp
# at the post's top, scripts/make_fem_specimens.py).
RECONSTRUCTIONS = [("disk target", "disk_100N", ()), ("kitten target", "kitten", ()), ("300 N disk", "disk_300N", ()),
                   ("600 N disk", "disk_600N", ()), ("stacked disks", "stacked_disks", ()),
                   ("bracket (FEM), loads not given", "bracket", ()),
                   ("bracket (FEM), tip and clamp given", "bracket", ("box:59,-1,-6,61,11,6", "box:-1,49,-6,11,51,6")),
                   ("shaft in torsion", "shaft_torsion", ()), ("Lame cylinder", "lame_cylinder", ()),
                   ("Boussinesq", "boussinesq", ()), ("disk in water", "disk_water", ())]


def exact_case(name, make, point_loads, resolution) -> dict:
    scene = make()
    truth = specimen_media(scene)[0].field
    start = time.perf_counter()
    result = separate(None, scene, resolution=resolution)
    seconds = time.perf_counter() - start
    points = inside_nodes(result)
    found, true = result.field_values(points), sample(truth, points)
    size = float(np.max(points.max(axis=0) - points.min(axis=0)))
    loads = result.loaded_points if point_loads is None else np.asarray(point_loads)
    away = cKDTree(loads).query(points)[0] > 0.1 * size if len(loads) else np.ones(len(points), bool)
    everywhere, far = errors(found, true), errors(found[away], true[away])
    return {"case": name, "source": "exact deviator", "grid": "x".join(map(str, result.summary["grid"])),
            "mean_error_all": round(everywhere["mean_per_scale"], 5),
            "mean_error_away": round(far["mean_per_scale"], 5),
            "full_error_away": round(far["full"], 5), "deviatoric_error": round(everywhere["deviatoric"], 5),
            "free_surface_shear": result.summary["residual"]["free_surface_shear_per_scale"],
            "loaded_share": round(1 - result.summary["loaded"]["free_share"], 4),
            "seconds": round(seconds, 2), "cells": result.summary["cells"]}


def reconstruction_case(name, directory: Path, loaded=()) -> dict:
    source = open_source(directory)
    truth = source.truth()
    start = time.perf_counter()
    result = separate(source.field, source.scene, loaded)
    seconds = time.perf_counter() - start
    compared = against_truth(result, truth.field or specimen_media(truth.scene)[0].field)
    everywhere, far = compared["all"], compared.get("away_from_loads", compared["all"])
    return {"case": name, "source": f"reconstruction ({directory.name})",
            "grid": "x".join(map(str, result.summary["grid"])),
            "mean_error_all": everywhere["mean_per_scale"], "mean_error_away": far["mean_per_scale"],
            "full_error_all": everywhere["full"], "full_error_away": far["full"],
            "deviatoric_error": everywhere["deviatoric"],
            "full_over_deviatoric": round(everywhere["full"] / everywhere["deviatoric"], 3),
            "free_surface_shear": result.summary["residual"]["free_surface_shear_per_scale"],
            "loaded_share": round(1 - result.summary["loaded"]["free_share"], 4),
            "seconds": round(seconds, 2), "cells": result.summary["cells"]}


def cube_child(resolution: int) -> None:
    scene = bar((10.0, 10.0, 10.0), xx=6.0, xy=2.0)
    start = time.perf_counter()
    result = separate(None, scene, resolution=resolution)
    print(json.dumps({"seconds": time.perf_counter() - start, "cells": result.summary["cells"],
                      "grid": result.summary["grid"], "iterations": result.summary["iterations"],
                      "peak_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20}))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="resolution 32 only, no kitten, no reconstructions")
    parser.add_argument("--csv", type=Path, help="the table's CSV (default: experiments/results/separation.csv; "
                                                 "--quick: experiments/out/separation_quick.csv)")
    parser.add_argument("--cube-child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.cube_child:
        return cube_child(args.cube_child)
    rows = []
    resolutions = (32,) if args.quick else (32, 48, 64)
    for name, make, point_loads in CASES:
        if args.quick and "kitten" in name:
            continue
        for resolution in ((None,) if "kitten" in name else resolutions):
            rows.append(exact_case(name, make, point_loads, resolution))
            print(rows[-1], flush=True)
    if not args.quick:
        for name, case, loaded in RECONSTRUCTIONS:
            if (SUITE / case).is_dir():
                rows.append(reconstruction_case(name, SUITE / case, loaded))
                print(rows[-1], flush=True)
    size = 32 if args.quick else 64
    child = subprocess.run([sys.executable, __file__, "--cube-child", str(size)], capture_output=True, text=True,
                           check=True)
    cube = json.loads(child.stdout.strip().splitlines()[-1])
    rows.append({"case": f"{size}^3 lattice (a cube)", "source": "speed", "grid": "x".join(map(str, cube["grid"])),
                 "seconds": round(cube["seconds"], 2), "cells": cube["cells"], "peak_gib": round(cube["peak_gib"], 2)})
    print(rows[-1])
    columns = sorted({key for row in rows for key in row}, key=lambda k: list(rows[0]).index(k)
                     if k in rows[0] else 100)
    output = args.csv or HERE / "experiments" / ("out" if args.quick else "results") / \
        ("separation_quick.csv" if args.quick else "separation.csv")
    output.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile("w", dir=output.parent, delete=False, suffix=".csv") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns + ["cpu"])
        writer.writeheader()
        for row in rows:
            writer.writerow({**row, "cpu": cpu_name()})
    Path(handle.name).replace(output)
    print(f"{cpu_name()}; wrote {output}")


if __name__ == "__main__":
    main()
