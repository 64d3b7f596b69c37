"""NeST-general against NeST-approx (the paper's forward-model comparison) on one dataset.

Both reconstruct the same simulated dataset with the same field and budget;
only the forward model differs: ``product`` (exact per-step exponentials) or
``linear`` (one exponential of the summed stress: wrong where the principal
axes turn along the rays, as between two disks loaded at different angles).
Writes ``forward_models.csv`` and ``forward_models.png`` (loss against wall
time) to ``--output``:

    .venv/bin/python experiments/forward_models.py --scene stacked_disks --minutes 5

The Two-step baseline (per-view unwrapping, then linear tomography) is not
implemented yet; see docs/reconstruction.md.
"""
from __future__ import annotations

import argparse
import csv
import warnings
from pathlib import Path

import mi_nest
from mi_nest.dataset import SimulationSettings, simulate

MODELS = {"NeST-general": "product", "NeST-approx": "linear"}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="stacked_disks")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--rotations", type=int, default=16)
    parser.add_argument("--res", type=int, default=48)
    parser.add_argument("--minutes", type=float, default=5.0, help="per model")
    parser.add_argument("--resolution", type=int, default=24, help="grid nodes along the longest axis")
    parser.add_argument("--output", type=Path, default=Path("experiments/out/forward_models"))
    args = parser.parse_args()
    defines = dict(d.split("=", 1) for d in args.defines)
    data = args.output / "data" / f"{args.scene}_{args.rotations}x{args.rotations}_{args.res}"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        simulate(args.scene, data, SimulationSettings(azimuths=args.rotations, elevations=args.rotations,
                                                      res=args.res), defines=defines, progress=False)
    rows, histories = [], {}
    for label, method in MODELS.items():
        scene = mi_nest.load_scene(args.scene, res=args.res, **defines)
        result = mi_nest.optimize(scene, data, output=args.output / "results" / label, resume=False,
                                  method=method, kind="grid", resolution=args.resolution, iterations=100_000,
                                  time_limit=60.0 * args.minutes, batch_size=2048, learning_rate=0.05,
                                  final_learning_rate=0.002)
        rows.append({"model": label, "method": method, "iterations": len(result.history),
                     "seconds": round(result.seconds, 1),
                     "deviatoric_error": round(result.metrics["deviatoric_error"], 4),
                     "representation_floor": round(result.metrics.get("representation_floor", float("nan")), 4),
                     "principal_difference_error": round(result.metrics["principal_difference_error"], 4),
                     "test_psnr": round(result.metrics["test_psnr"], 2)})
        histories[label] = result.history
        print(rows[-1], flush=True)
    args.output.mkdir(parents=True, exist_ok=True)
    with open(args.output / "forward_models.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    figure, axis = plt.subplots(figsize=(6, 4))
    for row in rows:
        history = histories[row["model"]]
        axis.plot([h["seconds"] for h in history], [h["loss"] for h in history], lw=0.5,
                  label=f"{row['model']}: {100 * row['deviatoric_error']:.1f}% error, PSNR {row['test_psnr']:.1f} dB")
    axis.set(xlabel="optimisation time (s)", ylabel="batch L1 loss", yscale="log", title=args.scene)
    axis.legend()
    figure.tight_layout()
    figure.savefig(args.output / "forward_models.png", dpi=120)
    print(f"wrote {args.output / 'forward_models.csv'} and {args.output / 'forward_models.png'}")


if __name__ == "__main__":
    main()
