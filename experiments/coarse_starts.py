"""Several starts for the coarsest stage: do random starts, chosen by the held-out loss, find the right branch?

The 600 N disk's run from zero already ends on a wrong branch at its coarsest stage (8 nodes across). Here that
stage alone (``--resolution 8``, one stage) runs for ``--seconds`` from each start, written as a grid file on
the stage's own nodes and given as ``start=`` (as given, not scaled): zero; random fields of a given RMS (stress
scales, normal at each node); and the truth's best 8-node grid (least squares) scaled by 0.5 to 1.5, the
structured starts a model of the part would give. Prints and writes ``coarse_starts.csv``: each start's final
error and held-out PSNR, and the rank correlation between them (whether the held-out loss would pick the best).

    .venv/bin/python experiments/coarse_starts.py --seconds 20

The dataset is the accuracy suite's ``disk_600N`` (``benchmarks/accuracy_suite.py``, simulated there first).
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import common
import numpy as np
from scipy.stats import spearmanr

import mi_nest
from mi_nest.dataset import Dataset
from mi_nest.dataset.truth import recorded_truth
from mi_nest.fields.base import sample
from mi_nest.io.grid import StressGrid, grid_nodes, save_stress_grid
from mi_nest.reconstruct import FieldConfig, make_field, metrics
from mi_nest.reconstruct.optimization import stress_scale
from mi_nest.scene import specimen_bounds, specimen_media, specimen_shapes

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
from reconstruction import cpu_name  # noqa: E402

DATA = HERE / "experiments" / "out" / "accuracy_suite" / "data" / "disk_600N_32x32_64"
RESOLUTION = 8
RANDOM_RMS = (0.5, 1.0, 2.0)
RANDOM_SEEDS = (0, 1)
TRUTH_SCALES = (0.5, 0.8, 1.0, 1.5)


def grid_file(path: Path, field, nodes: np.ndarray) -> Path:
    """``nodes`` (five stored components per node, stress scales) of the grid ``field`` as a stress grid file on the
    same nodes."""
    field.set_nodes(nodes)
    stress = sample(field, grid_nodes(field.bbox_min, field.bbox_max, field.shape))
    save_stress_grid(path, StressGrid(stress.reshape(*field.shape[::-1], 6).astype(np.float32), field.bbox_min,
                                      field.bbox_max))
    return path


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="of optimisation per start")
    parser.add_argument("--output", type=Path, default=HERE / "experiments" / "out" / "coarse_starts")
    args = parser.parse_args()
    if not (DATA / "dataset.json").is_file():
        raise SystemExit(f"{DATA} is missing: run python benchmarks/accuracy_suite.py --cases disk_600N first")
    dataset = Dataset(DATA)
    scene, truth = recorded_truth(dataset)
    shapes = specimen_shapes(scene)
    low, high = specimen_bounds(shapes)
    field = make_field(FieldConfig(kind="grid", resolution=RESOLUTION), low, high,
                       stress_scale(specimen_media(scene), low, high))
    best = metrics.fitted_nodes(field, truth, metrics.evaluation_points(scene, shapes, 3 * metrics.EVALUATION_POINTS))
    starts = {"zero": None}
    starts.update({f"truth's best grid x {s:g}": s * best for s in TRUTH_SCALES})
    for rms in RANDOM_RMS:
        for seed in RANDOM_SEEDS:
            starts[f"random, RMS {rms:g}, seed {seed}"] = rms * np.random.default_rng(seed).normal(size=best.shape)
    args.output.mkdir(parents=True, exist_ok=True)
    rows = []
    print(f"CPU: {cpu_name()}; the truth's best {RESOLUTION}-node grid has an RMS of "
          f"{np.sqrt(np.mean(best ** 2)):.2f} stress scales", flush=True)
    for label, nodes in starts.items():
        options = {} if nodes is None else {"start": str(grid_file(args.output / f"start{len(rows)}.npz", field,
                                                                   nodes)), "start_scale_range": 0.0}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            result = mi_nest.optimize(scene, dataset, progress=False, resolution=RESOLUTION, coarse_to_fine=False,
                                      iterations=1_000_000_000, time_limit=args.seconds, track_error_every=10_000,
                                      **options)
        rows.append({"start": label, "start_error": round(result.history[0]["deviatoric_error"], 4),
                     "deviatoric_error": round(result.metrics["deviatoric_error"], 4),
                     "test_psnr": round(result.metrics["test_psnr"], 2), "iterations": len(result.history),
                     "seconds": args.seconds, "cpu": cpu_name()})
        print(rows[-1], flush=True)
        common.write_table(rows, HERE / "experiments" / "results" / "coarse_starts.csv")
    correlation = spearmanr([r["deviatoric_error"] for r in rows], [-r["test_psnr"] for r in rows]).statistic
    print(f"rank correlation of the error with the held-out loss (-PSNR) over the {len(rows)} starts: "
          f"{correlation:.2f}")


if __name__ == "__main__":
    main()
