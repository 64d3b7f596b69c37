"""Whether a network's error is its representation's or its descent's: the network fitted to the truth directly.

For each saved reconstruction by a network sampled on a lattice (``mi-nest reconstruct DATA --kind mlp`` or
``hashgrid``, of a simulated dataset such as the accuracy suite's), a fresh network of the same configuration and
seed is fitted by Adam, at the run's own first learning rate, to the truth's best grid on the same lattice (least
squares, ``metrics.fitted_nodes``): the mean squared difference at the lattice's nodes, no rendering. Its
relative deviatoric error after ``--steps`` is what the network can hold on that lattice; where it ends far below
the reconstruction's, the reconstruction's error is the descent through the renderer, not the representation.

    .venv/bin/python experiments/network_floor.py experiments/out/accuracy_suite/accuracy_suite/disk_100N_mlp

Writes ``experiments/results/network_floor.csv`` (a row per result and step count) and prints the CPU.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import common
import drjit as dr
import mitsuba as mi
import numpy as np

import mi_nest  # noqa: F401  (sets the variant)
from mi_nest.reconstruct import Reconstruction, make_field, metrics
from mi_nest.scene import specimen_shapes

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
from accuracy_suite import read_rows  # noqa: E402
from reconstruction import cpu_name  # noqa: E402


def floor_rows(directory: Path, steps: list[int]) -> list[dict]:
    result = Reconstruction.load(directory)
    found = result.field
    if found.shape is None or found.kind == "grid":
        raise SystemExit(f"{directory}: not a network sampled on a lattice ({found.describe()}); for grids "
                         "grid_floor.py gives the floor")
    dataset, scene, truth = common.simulated_from(result)
    shapes = specimen_shapes(scene)
    probe = metrics.ErrorProbe(truth, metrics.evaluation_points(scene, shapes))
    best = metrics.fitted_nodes(found.samples, truth,
                                metrics.evaluation_points(scene, shapes, 3 * metrics.EVALUATION_POINTS))
    found.samples.set_nodes(best)
    best_error = probe(found.samples)
    network = make_field(found.config, found.bbox_min, found.bbox_max, found.stress_scale)
    # Made from the result's configuration, it is sampled on the result's own lattice.
    target = [mi.Float(best[:, component].astype(np.float32)) for component in range(5)]
    learning_rate = result.config.optimiser.learning_rate
    optimiser = dr.opt.Adam(lr=learning_rate, params=network.parameters())
    rows, done, began = [], 0, time.perf_counter()
    for count in sorted(set(steps)):
        loss = network.fit_at_nodes(target, optimiser, count - done)
        done = count
        network.assign(optimiser)
        rows.append({"result": directory.name, "field": found.describe(),
                     "reconstruction_error": round(float(result.metrics["deviatoric_error"]), 4),
                     "reconstruction_iterations": len(result.history), "best_grid_error": round(best_error, 4),
                     "learning_rate": learning_rate, "steps": done, "node_mse": round(loss, 5),
                     "fitted_error": round(probe(network), 4),
                     "seconds": round(time.perf_counter() - began, 1), "cpu": cpu_name()})
        print(rows[-1], flush=True)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="+", type=Path, help="reconstructions by networks sampled on a lattice")
    parser.add_argument("--steps", default="500,2000,5000", help="Adam steps at which to score the fit")
    args = parser.parse_args()
    try:
        steps = [int(s) for s in args.steps.split(",")]
    except ValueError:
        raise SystemExit(f"--steps {args.steps!r}: give whole numbers separated by commas, e.g. 500,2000")
    table = HERE / "experiments" / "results" / "network_floor.csv"
    rows = read_rows(table)
    print(f"CPU: {cpu_name()}", flush=True)
    for directory in args.results:
        fresh = floor_rows(directory, steps)
        rows = [r for r in rows if r["result"] != directory.name] + fresh
        common.write_table(rows, table)
    print(f"wrote {table}")


if __name__ == "__main__":
    main()
