"""How much of the rotation range NeST needs: 180, 90 and 45 degrees on both axes (the paper's study).

The same number of rotations spread over a smaller range each time; the same
field, forward model and time budget. Writes ``rotation_range.csv`` and
``rotation_range.png`` (stress error against optimisation time):

    .venv/bin/python experiments/rotation_range.py --scene disk_compression -D load=300 -D contact_width=4
"""
from __future__ import annotations

import common


def main():
    parser = common.arguments(__doc__, "rotation_range")
    parser.add_argument("--ranges", type=float, nargs="+", default=[180.0, 90.0, 45.0])
    args, defines = common.parse(parser)
    rows, results = [], []
    for degrees in args.ranges:
        data, simulated = common.dataset(args.scene, args.output, args.rotations, args.res, defines,
                                         azimuth_range=degrees, elevation_range=degrees)
        label = f"{degrees:g} deg"
        row, result = common.reconstruct(args.scene, data, args.output, label, args.minutes, args.res, defines,
                                         kind="grid", resolution=args.resolution, track_error_every=250)
        rows.append({"range_deg": degrees, "simulate_s": round(simulated, 1), **row})
        results.append((label, result))
    common.finish(args, rows, results, "rotation range")

if __name__ == "__main__":
    main()
