"""Learning rates for the networks: the grid's default (0.05 stress scales per step) made the paper's MLP run away
on the accuracy suite's disk target (``--kind mlp``: diverged at iteration 100). Each case reconstructs the same
dataset for the same time with one learning rate (decaying 25-fold over the run, as the grid's does); a run that
diverges is recorded as such. Writes ``network_learning_rate.csv`` and ``.png``:

    .venv/bin/python experiments/network_learning_rate.py --minutes 2

The dataset is the accuracy suite's disk target (``benchmarks/accuracy_suite.py``; simulated there first).
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import common
import mi_nest
from mi_nest.reconstruct import DivergenceError

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
from reconstruction import cpu_name  # noqa: E402

DATA = HERE / "experiments" / "out" / "accuracy_suite" / "data" / "disk_100N_32x32_64"
RATES = {"mlp": (3e-2, 1e-2, 3e-3, 1e-3), "hashgrid": (5e-2, 1e-2, 3e-3)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=2.0, help="of optimisation per run")
    parser.add_argument("--kinds", default="mlp,hashgrid")
    parser.add_argument("--output", type=Path, default=HERE / "experiments" / "out" / "network_learning_rate")
    args = parser.parse_args()
    if not (DATA / "dataset.json").is_file():
        raise SystemExit(f"{DATA} is missing: run python benchmarks/accuracy_suite.py --cases disk_100N first")
    rows, results = [], []
    for kind in args.kinds.split(","):
        for rate in RATES[kind]:
            label = f"{kind} at {rate:g}"
            scene = mi_nest.load_scene("disk_compression", load=100, contact_width=4, res=64)
            start = time.perf_counter()
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    result = mi_nest.optimize(scene, DATA, output=args.output / "results" / label.replace(" ", "_"),
                                              resume=False, progress=False, kind=kind, resolution=0,
                                              learning_rate=rate,
                                              final_learning_rate=rate / 25, iterations=1_000_000,
                                              time_limit=60.0 * args.minutes, track_error_every=25)
            except DivergenceError as error:
                rows.append({"kind": kind, "learning_rate": rate, "iterations": "", "optimise_s": "",
                             "deviatoric_error": "", "test_psnr": "", "outcome": str(error).split(";")[0],
                             "cpu": cpu_name()})
                print(rows[-1], flush=True)
                continue
            metrics = result.metrics
            rows.append({"kind": kind, "learning_rate": rate, "iterations": len(result.history),
                         "optimise_s": round(result.seconds, 1),
                         "deviatoric_error": round(metrics["deviatoric_error"], 4),
                         "test_psnr": round(metrics["test_psnr"], 2),
                         "outcome": f"finished in {time.perf_counter() - start:.0f} s", "cpu": cpu_name()})
            print(rows[-1], flush=True)
            results.append((label, result))
    args.name = "network_learning_rate"
    args.scene = "disk_compression"
    common.finish(args, rows, results, "network learning rates, the disk target's dataset")


if __name__ == "__main__":
    main()
