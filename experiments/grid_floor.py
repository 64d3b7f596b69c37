"""How fine a grid a part needs: the best grid's deviatoric error (the floor no reconstruction on it goes below)
against the grid's resolution, and where the error of the finest sits.

For each resolution (nodes along the part's longest side, the other sides in proportion as ``mi-nest
reconstruct --resolution N`` makes them) the grid is fitted to the scene's own field in the least-squares sense
on a lattice three times finer than the evaluation points (``metrics.best_fit_floor``, the floor the accuracy
suite and ``loss_landscape.py`` report), and scored at the evaluation points as a reconstruction is. For a
singular field (Boussinesq's point load) the error then sits near the singularity: the script also reports the
share of the squared error within ``--near`` mm of the point of greatest stress, and the error with that ball
left out, and the share of the true deviator's squared norm there. ``--results`` scores saved reconstructions of
the scene the same way (what a reconstruction reached beside what its grid could). Prints and writes
``grid_floor_SCENE.csv``. The fit's sparse factorisation grows fast with the nodes (Boussinesq: 8 s on 48 nodes,
44 s on 64, AMD EPYC Zen 4):

    .venv/bin/python experiments/grid_floor.py --scene boussinesq --resolutions 32,48,64 --results OUT
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import common
import numpy as np

import mi_nest
from mi_nest.fields.base import sample
from mi_nest.physics.tensors import deviatoric_part, tensor_norm
from mi_nest.reconstruct import FieldConfig, Reconstruction, make_field, metrics
from mi_nest.reconstruct.optimization import stress_scale
from mi_nest.scene import scene_field, specimen_bounds, specimen_media, specimen_shapes

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
from reconstruction import cpu_name  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="boussinesq")
    parser.add_argument("--resolutions", default="32,48,64", help="nodes along the longest side")
    parser.add_argument("--results", nargs="*", type=Path, default=[], help="reconstruction output directories "
                                                                           "of the same scene to score")
    parser.add_argument("--near", type=float, default=4.0, help="radius (mm) of the ball about the greatest "
                                                                "stress whose share of the error is reported")
    args = parser.parse_args()
    try:
        resolutions = [int(r) for r in args.resolutions.split(",")]
    except ValueError:
        raise SystemExit(f"--resolutions {args.resolutions!r}: give whole numbers separated by commas, e.g. 32,64")
    scene = mi_nest.load_scene(args.scene, res=64)
    shapes = specimen_shapes(scene)
    low, high = specimen_bounds(shapes)
    truth = scene_field(scene)
    points = metrics.evaluation_points(scene, shapes)
    fit_points = metrics.evaluation_points(scene, shapes, 3 * metrics.EVALUATION_POINTS)
    probe = metrics.ErrorProbe(truth, points)
    reference = probe.reference
    peak = points[np.argmax(tensor_norm(reference))]
    near = np.linalg.norm(points - peak, axis=1) < args.near
    truth_near = float((tensor_norm(reference[near]) ** 2).sum() / (tensor_norm(reference) ** 2).sum())
    rows = []
    print(f"CPU: {cpu_name()}; {len(points)} evaluation points, {near.sum()} within {args.near:g} mm of the "
          f"greatest stress at {np.round(peak, 2).tolist()} mm", flush=True)

    def row(what, field, seconds):
        estimate = deviatoric_part(sample(field, points))
        squared = tensor_norm(estimate - reference) ** 2
        rows.append({"scene": args.scene, "field": what, "grid": "x".join(map(str, field.shape)),
                     "nodes": int(np.prod(field.shape)), "error": round(probe.error_of(estimate), 4),
                     "share_of_squared_error_near": round(float(squared[near].sum() / squared.sum()), 4),
                     "share_of_squared_truth_near": round(truth_near, 4),
                     f"error_beyond_{args.near:g}mm": round(float(np.sqrt(
                         squared[~near].sum() / (tensor_norm(reference[~near]) ** 2).sum())), 4),
                     "seconds": round(seconds, 1), "cpu": cpu_name()})
        print(rows[-1], flush=True)

    for resolution in resolutions:
        began = time.perf_counter()
        field = make_field(FieldConfig(kind="grid", resolution=resolution), low, high,
                           stress_scale(specimen_media(scene), low, high))
        field.set_nodes(metrics.fitted_nodes(field, truth, fit_points))
        row(f"best grid, {resolution} nodes", field, time.perf_counter() - began)
    for directory in args.results:
        result = Reconstruction.load(directory)
        _, _, recorded = common.simulated_from(result)
        if not np.allclose(deviatoric_part(sample(recorded, points)), reference, rtol=1e-4, atol=1e-6):
            raise SystemExit(f"{directory}: its dataset holds another field than --scene {args.scene}'s defaults")
        row(f"reconstruction {directory.name}", result.field, 0.0)
    common.write_table(rows, HERE / "experiments" / "results" / f"grid_floor_{args.scene}.csv")


if __name__ == "__main__":
    main()
