"""What every reconstruction experiment does: simulate a dataset once, reconstruct within a budget, tabulate, plot.

Each experiment script varies one thing (forward model, rotation range,
stress-optic coefficient, field representation) and calls these; datasets are
kept under ``OUTPUT/data`` and reused (simulation resumes), results go to
``OUTPUT/results/LABEL``.
"""
from __future__ import annotations

import argparse
import csv
import time
import warnings
from pathlib import Path

import mi_nest
from mi_nest.dataset import Dataset, SimulationSettings, simulate
from mi_nest.dataset.truth import recorded_truth
from mi_nest.reconstruct import NO_REGULARISER

# Every experiment's optimiser settings, unless it varies them: the clock ends the runs, and the fit is plain
# (as when the experiments were first run; those that study the regulariser give it).
OPTIONS = dict(batch_size=2048, learning_rate=0.05, final_learning_rate=0.002, iterations=100_000,
               regulariser=NO_REGULARISER)


def arguments(doc, name, scene="disk_compression", defines=("load=300", "contact_width=4"), rotations=32, res=64,
              minutes=3.0, resolution=32):
    """The options every experiment shares; ``name`` names its output folder, CSV and PNG."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--scene", default=scene)
    parser.add_argument("-D", dest="defines", action="append", metavar="NAME=VALUE",
                        help=f"scene defines; they replace the defaults ({' '.join(defines) or 'none'}, which are "
                             f"for {scene} only)")
    parser.add_argument("--rotations", type=int, default=rotations)
    parser.add_argument("--res", type=int, default=res)
    parser.add_argument("--minutes", type=float, default=minutes, help="of optimisation per run")
    parser.add_argument("--resolution", type=int, default=resolution, help="grid nodes along the longest axis")
    parser.add_argument("--output", type=Path, default=Path("experiments/out") / name)
    parser.set_defaults(name=name, default_scene=scene, default_defines=list(defines))
    return parser


def parse(parser):
    """``(args, defines)`` with the ``-D`` defines as numbers."""
    args = parser.parse_args()
    if args.defines is None:
        # The defaults are the default scene's: another scene may not have those parameters.
        args.defines = args.default_defines if args.scene == args.default_scene else []
    return args, {k: float(v) for k, v in (d.split("=", 1) for d in args.defines)}


def finish(args, rows, results, title):
    """The experiment's table and its chart of stress error against optimisation time."""
    write_table(rows, args.output / f"{args.name}.csv")
    plot_histories(results, args.output / f"{args.name}.png", f"{args.scene}: {title}", key="deviatoric_error",
                   ylabel="relative deviatoric stress error")


def dataset_directory(scene, output, rotations, res, defines=None, **settings):
    """Where :func:`dataset` keeps ``scene`` simulated so."""
    tag = "".join(f"_{k}{v:g}" for k, v in sorted(dict(defines or {}).items()))
    tag += "".join(f"_{k}{v:g}" for k, v in sorted(settings.items()) if k != "camera")
    camera = settings.get("camera")
    if camera is not None and camera.read_noise:
        tag += f"_noise{camera.read_noise:g}"
    return Path(output) / "data" / f"{scene}{tag}_{rotations}x{rotations}_{res}"


def dataset(scene, output, rotations, res, defines=None, **settings):
    """Simulate (or resume) ``scene`` at ``rotations`` x ``rotations``; returns ``(directory, seconds)``."""
    defines = dict(defines or {})
    directory = dataset_directory(scene, output, rotations, res, defines, **settings)
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        simulate(scene, directory, SimulationSettings(azimuths=rotations, elevations=rotations, res=res, **settings),
                 defines=defines, progress=False)
    return directory, time.perf_counter() - start


def reconstruct(scene, data, output, label, minutes, res, defines=None, **options):
    """Reconstruct ``data`` for ``minutes`` of optimisation; returns ``(row, result)``."""
    defines = dict(defines or {})
    loaded = mi_nest.load_scene(scene, res=res, **defines)
    start = time.perf_counter()
    result = mi_nest.optimize(loaded, data, output=Path(output) / "results" / label, resume=False, progress=False,
                              time_limit=60.0 * minutes, **{**OPTIONS, **options})
    metrics = result.metrics
    row = {"label": label, "iterations": len(result.history), "optimise_s": round(result.seconds, 1),
           "total_s": round(time.perf_counter() - start, 1),
           "deviatoric_error": round(metrics.get("deviatoric_error", float("nan")), 4),
           "grid_floor": round(metrics.get("grid_floor", float("nan")), 4),
           "principal_difference_error": round(metrics.get("principal_difference_error", float("nan")), 4),
           "test_psnr": round(metrics.get("test_psnr", float("nan")), 2)}
    print(row, flush=True)
    return row, result


def simulated_from(result):
    """``(dataset, scene, truth)`` of a reconstruction of a simulated dataset: the dataset, the scene it was
    rendered from and the stress field it was simulated with."""
    dataset = Dataset(result.source["dataset"])
    return (dataset, *recorded_truth(dataset))


def write_table(rows, path):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(dict.fromkeys(key for row in rows for key in row))
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=names)
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {path}")


def pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_histories(results, path, title, key="loss", ylabel="batch L1 loss"):
    """One curve per labelled result: ``key`` of its history against optimisation time."""
    plt = pyplot()
    figure, axis = plt.subplots(figsize=(6.5, 4))
    for label, result in results:
        points = [(h["seconds"], h[key]) for h in result.history if key in h]
        error = result.metrics.get("deviatoric_error", float("nan"))
        axis.plot(*zip(*points), lw=0.8 if key != "loss" else 0.5,
                  label=f"{label}: {100 * error:.1f}% error, PSNR {result.metrics.get('test_psnr', float('nan')):.1f} dB")
    axis.set(xlabel="optimisation time (s)", ylabel=ylabel, yscale="log", title=title)
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    print(f"wrote {path}")
