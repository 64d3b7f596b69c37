"""How much of the rotation range NeST needs: 180, 90 and 45 degrees on both axes (the paper's study).

The same number of rotations spread over a smaller range each time; the same
field, forward model and time budget. Writes ``rotation_range.csv`` and
``rotation_range.png`` (stress error against optimisation time):

    .venv/bin/python experiments/rotation_range.py --scene disk_compression -D load=300 -D contact_width=4
"""
from __future__ import annotations

import argparse
from pathlib import Path

import common


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="disk_compression")
    parser.add_argument("-D", dest="defines", action="append", default=["load=300", "contact_width=4"],
                        metavar="NAME=VALUE")
    parser.add_argument("--ranges", type=float, nargs="+", default=[180.0, 90.0, 45.0])
    parser.add_argument("--rotations", type=int, default=32)
    parser.add_argument("--res", type=int, default=64)
    parser.add_argument("--minutes", type=float, default=3.0, help="per range")
    parser.add_argument("--resolution", type=int, default=32, help="grid nodes along the longest axis")
    parser.add_argument("--output", type=Path, default=Path("experiments/out/rotation_range"))
    args = parser.parse_args()
    defines = {k: float(v) for k, v in (d.split("=", 1) for d in args.defines)}
    rows, results = [], []
    for degrees in args.ranges:
        data, simulated = common.dataset(args.scene, args.output, args.rotations, args.res, defines,
                                         azimuth_range=degrees, elevation_range=degrees)
        label = f"{degrees:g} deg"
        row, result = common.reconstruct(args.scene, data, args.output, label, args.minutes, args.res, defines,
                                         kind="grid", resolution=args.resolution, track_error_every=250)
        rows.append({"range_deg": degrees, "simulate_s": round(simulated, 1), **row})
        results.append((label, result))
    common.write_table(rows, args.output / "rotation_range.csv")
    common.plot_histories(results, args.output / "rotation_range.png", f"{args.scene}: rotation range",
                          key="deviatoric_error", ylabel="relative deviatoric stress error")


if __name__ == "__main__":
    main()
