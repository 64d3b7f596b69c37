"""NeST-general against NeST-approx and Two-step (the paper's forward-model comparison) on one dataset.

All three reconstruct the same simulated dataset with the same field and time
budget: ``product`` (exact per-step exponentials, NeST-general), ``linear``
(one exponential of the summed stress: wrong where the principal axes turn
along the rays, as between two disks loaded at different angles; NeST-approx)
and ``two-step`` (per-view Jones recovery and phase unwrapping, then linear
tomography). Writes ``forward_models.csv`` and ``forward_models.png`` (stress
error against optimisation time) to ``--output``:

    .venv/bin/python experiments/forward_models.py --scene stacked_disks --minutes 4
"""
from __future__ import annotations

import argparse
from pathlib import Path

import common

MODELS = {"NeST-general": "product", "NeST-approx": "linear", "Two-step": "two-step"}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="stacked_disks")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--rotations", type=int, default=16)
    parser.add_argument("--res", type=int, default=48)
    parser.add_argument("--minutes", type=float, default=4.0, help="per model")
    parser.add_argument("--resolution", type=int, default=24, help="grid nodes along the longest axis")
    parser.add_argument("--output", type=Path, default=Path("experiments/out/forward_models"))
    args = parser.parse_args()
    defines = {k: float(v) for k, v in (d.split("=", 1) for d in args.defines)}
    data, _ = common.dataset(args.scene, args.output, args.rotations, args.res, defines)
    rows, results = [], []
    for label, method in MODELS.items():
        row, result = common.reconstruct(args.scene, data, args.output, label, args.minutes, args.res, defines,
                                         method=method, kind="grid", resolution=args.resolution,
                                         track_error_every=250)
        rows.append({"model": label, "method": method, **row})
        results.append((label, result))
    common.write_table(rows, args.output / "forward_models.csv")
    common.plot_histories(results, args.output / "forward_models.png", f"{args.scene}: forward models",
                          key="deviatoric_error", ylabel="relative deviatoric stress error")


if __name__ == "__main__":
    main()
