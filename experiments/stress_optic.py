"""Fringe density: stress-optic coefficient 0.1, 0.25 and 0.5 under read noise 0.01 (the paper's study).

The paper scales its normalised stress-optic coefficient; here the scene's
fringe value (MPa mm per fringe) is divided by ``coefficient / 0.25``, so 0.25
is the scene as shipped (with ``-D`` defines), 0.5 has twice its fringes and
0.1 has 0.4 times as many. Every dataset gets Gaussian read noise of 0.01 (in
normalised intensity), as in the paper. Writes ``stress_optic.csv`` and
``stress_optic.png``:

    .venv/bin/python experiments/stress_optic.py --scene disk_compression -D load=300 -D contact_width=4
"""
from __future__ import annotations

import mi_nest
from mi_nest.dataset import CameraModel
from mi_nest.scene import specimen_media

import common

REFERENCE_COEFFICIENT = 0.25


def main():
    parser = common.arguments(__doc__, "stress_optic")
    parser.add_argument("--coefficients", type=float, nargs="+", default=[0.1, 0.25, 0.5])
    parser.add_argument("--read-noise", type=float, default=0.01)
    args, defines = common.parse(parser)
    shipped = mi_nest.load_scene(args.scene, res=8, **defines)
    fringe_value = specimen_media(shipped)[0].fringe_value
    camera = CameraModel(read_noise=args.read_noise, seed=1)
    rows, results = [], []
    for coefficient in args.coefficients:
        scaled = {**defines, "fringe_value": fringe_value * REFERENCE_COEFFICIENT / coefficient}
        data, simulated = common.dataset(args.scene, args.output, args.rotations, args.res, scaled, camera=camera)
        label = f"C = {coefficient:g}"
        row, result = common.reconstruct(args.scene, data, args.output, label, args.minutes, args.res, scaled,
                                         kind="grid", resolution=args.resolution, track_error_every=250)
        rows.append({"coefficient": coefficient, "fringe_value": round(scaled["fringe_value"], 3),
                     "read_noise": args.read_noise, "simulate_s": round(simulated, 1), **row})
        results.append((label, result))
    common.finish(args, rows, results, f"stress-optic coefficient, read noise {args.read_noise:g}")

if __name__ == "__main__":
    main()
