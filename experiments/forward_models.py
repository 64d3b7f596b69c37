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

import common

MODELS = {"NeST-general": "product", "NeST-approx": "linear", "Two-step": "two-step"}


def main():
    parser = common.arguments(__doc__, "forward_models", scene="stacked_disks", defines=(), rotations=16, res=48,
                              minutes=4.0, resolution=24)
    args, defines = common.parse(parser)
    data, _ = common.dataset(args.scene, args.output, args.rotations, args.res, defines)
    rows, results = [], []
    for label, method in MODELS.items():
        row, result = common.reconstruct(args.scene, data, args.output, label, args.minutes, args.res, defines,
                                         method=method, kind="grid", resolution=args.resolution,
                                         track_error_every=250)
        rows.append({"model": label, "method": method, **row})
        results.append((label, result))
    common.finish(args, rows, results, "forward models")

if __name__ == "__main__":
    main()
