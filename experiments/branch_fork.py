"""When does a run choose its branch? Stop a run from zero at a given time, then resume copies of it with other seeds.

A copy resumed with its own seed goes on as the run would have; a copy whose checkpoint is given another seed
(the batches' generator and the steps' jitter: the ``seed`` option) draws other batches from there on. If every
copy ends where the first does, the state at the fork had already chosen the branch; if they scatter, the
batches after it choose. The run is the accuracy suite's case on its dataset (simulated there first), stopped
with Ctrl-C (SIGINT) once its checkpoint has passed ``--at`` seconds of optimisation. Writes
``experiments/results/branch_fork.csv`` (a row per copy, replacing the same fork's earlier row):

    .venv/bin/python experiments/branch_fork.py --case lame_cylinder --seed 1 --at 200 --fork-seeds 1,5
"""
from __future__ import annotations

import argparse
import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import common
import numpy as np

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
from accuracy_suite import CASES, CLI, dataset_directory, read_rows, run_command, simulate  # noqa: E402
from reconstruction import cpu_name  # noqa: E402

SUITE = HERE / "experiments" / "out" / "accuracy_suite"
TRACK_EVERY = 200


def checkpoint_seconds(directory: Path) -> float:
    """The optimisation time the directory's checkpoint holds; 0 before the first (or while one is written)."""
    try:
        with np.load(directory / "checkpoint.npz", allow_pickle=False) as data:
            return float(data["seconds"])
    except (OSError, ValueError, KeyError, EOFError):
        return 0.0


def reconstruct_arguments(data: Path, output: Path, minutes: float, seed: int) -> list[str]:
    """``mi-nest reconstruct``'s arguments for the run and for each copy (which resumes from its checkpoint)."""
    return [str(data), "-o", str(output), "--minutes", f"{minutes:g}", "--allow-aliased", "--no-progress",
            "--option", f"track_error_every={TRACK_EVERY}", "--option", f"seed={seed}"]


def run_until(data: Path, output: Path, minutes: float, seed: int, at: float) -> None:
    """A run from zero, stopped as Ctrl-C stops it once its checkpoint has passed ``at`` seconds."""
    command = [*CLI, "reconstruct", *reconstruct_arguments(data, output, minutes, seed), "--restart"]
    process = subprocess.Popen(command, cwd=HERE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    while process.poll() is None:
        if checkpoint_seconds(output) >= at:
            process.send_signal(signal.SIGINT)
            break
        time.sleep(0.5)
    _, errors = process.communicate()
    if checkpoint_seconds(output) < at:
        raise SystemExit(f"the run ended before {at:g} s: {errors.strip().splitlines()[-1:]}")


def fork(prefix: Path, output: Path, seed: int, prefix_seed: int) -> None:
    """A copy of ``prefix`` whose checkpoint resumes with ``seed`` (its own seed: as it was)."""
    if output.exists():
        shutil.rmtree(output)
    shutil.copytree(prefix, output)
    if seed == prefix_seed:
        return
    path = output / "checkpoint.npz"
    with np.load(path, allow_pickle=False) as data:
        state = {key: data[key] for key in data.files}
    config = json.loads(str(state["config"]))
    config["optimiser"]["seed"] = config["field"]["seed"] = seed
    state["config"] = np.array(json.dumps(config))
    state["rng"] = np.array(json.dumps(np.random.default_rng(seed).bit_generator.state))
    np.savez(path, **state)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    by_name = {case.name: case for case in CASES}
    parser.add_argument("--case", default="lame_cylinder", choices=sorted(by_name), metavar="CASE",
                        help="an accuracy suite case (default: lame_cylinder)")
    parser.add_argument("--seed", type=int, default=1, help="of the run before the fork (default: 1)")
    parser.add_argument("--at", type=float, default=200.0, help="seconds of optimisation at the fork (default: 200)")
    parser.add_argument("--fork-seeds", default="1,5", help="comma-separated seeds of the copies (default: 1,5)")
    parser.add_argument("--minutes", type=float, default=10.0, help="of the whole run, fork included")
    parser.add_argument("--output", type=Path, default=HERE / "experiments" / "out" / "branch_fork")
    args = parser.parse_args()
    seeds = [int(s) for s in args.fork_seeds.split(",")]
    if not 0 < args.at < 60 * args.minutes:
        raise SystemExit(f"--at must lie between 0 and the run's {60 * args.minutes:g} s, got {args.at:g}")
    case = by_name[args.case]
    data = dataset_directory(case, SUITE, case.rotations, case.res)
    simulate(case, data, case.rotations, case.res)
    print(f"CPU: {cpu_name()}", flush=True)
    name = f"{case.name}_seed{args.seed}_at{args.at:g}"
    prefix = args.output / name / "prefix"
    run_until(data, prefix, args.minutes, args.seed, args.at)
    with np.load(prefix / "checkpoint.npz", allow_pickle=False) as stopped:
        at, iteration = float(stopped["seconds"]), int(stopped["iteration"])
        tracked = [h["deviatoric_error"] for h in json.loads(str(stopped["history"])) if "deviatoric_error" in h]
    table = HERE / "experiments" / "results" / "branch_fork.csv"
    rows = read_rows(table)
    for seed in seeds:
        copy = args.output / name / f"seed{seed}"
        fork(prefix, copy, seed, args.seed)
        run_command("reconstruct", reconstruct_arguments(data, copy, args.minutes, seed))
        record = json.loads((copy / "reconstruction.json").read_text())
        row = {"case": case.name, "seed": args.seed, "at": args.at, "fork_seconds": round(at, 1),
               "fork_iteration": iteration,
               "error_at_fork": round(tracked[-1], 4) if tracked else "", "resumed_seed": seed,
               "deviatoric_error": round(record["metrics"]["deviatoric_error"], 4),
               "iterations": len(record["history"]), "test_psnr": round(record["metrics"]["test_psnr"], 2),
               "minutes": args.minutes, "cpu": cpu_name()}
        key = (case.name, str(args.seed), f"{args.at:g}", str(seed))
        rows = [r for r in rows if (r["case"], r["seed"], f"{float(r['at']):g}", r["resumed_seed"]) != key] + [row]
        print(json.dumps(row), flush=True)
        common.write_table(rows, table)


if __name__ == "__main__":
    main()
