"""Reconstruction error against wall time for every field representation and forward model.

Speed and accuracy both count: each (representation, forward model) pair
reconstructs the same dataset for the same optimisation time, the stress
error is recorded along the way (outside the timed steps), and the chart puts
one curve per pair on error against seconds. Writes ``error_vs_time.csv`` and
``error_vs_time.png``:

    .venv/bin/python experiments/error_vs_time.py --scene disk_compression -D load=300 -D contact_width=4
"""
from __future__ import annotations

import common

# Per representation: its options, and how often to record the error (the neural fields take far fewer steps).
# The networks are evaluated at every step, as NeST does (resolution 0), as when the recorded results were made.
KINDS = {"grid": {"kind": "grid", "track_error_every": 100},
         "hashgrid": {"kind": "hashgrid", "resolution": 0, "track_error_every": 20},
         "mlp": {"kind": "mlp", "resolution": 0, "learning_rate": 0.005, "final_learning_rate": 0.0005,
                 "track_error_every": 5}}
METHODS = ("product", "linear")


def main():
    parser = common.arguments(__doc__, "error_vs_time")
    parser.add_argument("--kinds", nargs="+", default=list(KINDS), choices=list(KINDS))
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    args, defines = common.parse(parser)
    data, _ = common.dataset(args.scene, args.output, args.rotations, args.res, defines)
    rows, results = [], []
    for kind in args.kinds:
        for method in args.methods:
            label = f"{kind}, {method}"
            options = {"resolution": args.resolution, "method": method, **KINDS[kind]}
            row, result = common.reconstruct(args.scene, data, args.output, label, args.minutes, args.res, defines,
                                             **options)
            rows.append({"kind": kind, "method": method, "parameters": result.field.parameter_count(),
                         "iterations_per_s": round(len(result.history) / max(result.seconds, 1e-9), 1), **row})
            results.append((label, result))
    common.finish(args, rows, results, "representations and forward models")

if __name__ == "__main__":
    main()
