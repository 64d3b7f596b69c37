"""What ``--deterministic`` costs: iterations per second of the same seeded run on all of Dr.Jit's threads and on
one (``deterministic=True``), side by side in one process, on the accuracy suite's disk target dataset; and
whether each setting repeats itself.

    .venv/bin/python benchmarks/deterministic_cost.py --iterations 1500
"""
from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import drjit as dr
import numpy as np

import mi_nest
from reconstruction import cpu_name

HERE = Path(__file__).resolve().parents[1]
DATA = HERE / "experiments" / "out" / "accuracy_suite" / "data" / "disk_100N_32x32_64"


def run(data: Path, deterministic: bool, iterations: int):
    scene = mi_nest.load_scene("disk_compression", load=100, contact_width=4, res=64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        result = mi_nest.optimize(scene, data, progress=False, iterations=iterations, deterministic=deterministic,
                                  evaluate_views=1)
    return result.seconds, np.array(result.field.texture.tensor()), result.metrics["deviatoric_error"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=1500)
    parser.add_argument("--data", type=Path, default=DATA,
                        help="a dataset of the disk target at 64 x 64 (default: the accuracy suite's)")
    args = parser.parse_args()
    if not (args.data / "dataset.json").is_file():
        raise SystemExit(f"{args.data} is missing: run python benchmarks/accuracy_suite.py --cases disk_100N first")
    print(f"CPU: {cpu_name()}, Dr.Jit threads: {dr.thread_count()}, {args.iterations} iterations each", flush=True)
    timings = {}
    for deterministic in (False, True):
        (first, field_a, error_a), (second, field_b, error_b) = (run(args.data, deterministic, args.iterations)
                                                                 for _ in range(2))
        label = "one thread (deterministic)" if deterministic else f"{dr.thread_count()} threads (default)"
        timings[deterministic] = min(first, second)
        print(f"{label}: {args.iterations / first:.1f} and {args.iterations / second:.1f} iterations/s; errors "
              f"{100 * error_a:.4f}% and {100 * error_b:.4f}%; grids differ by up to "
              f"{np.abs(field_a - field_b).max():.3g} stress scales", flush=True)
    print(f"deterministic / default time per iteration: {timings[True] / timings[False]:.2f}")


if __name__ == "__main__":
    main()
