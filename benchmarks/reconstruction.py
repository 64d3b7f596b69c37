"""Reconstruction throughput and result of this checkout against another, side by side in one run.

Each version runs in its own process from a copy of its tree laid out as a wheel
installs it (``mi_nest/`` with ``plugins/`` and ``scenes/`` inside), simulates the
same small dataset with its own code and reconstructs it with the same options
and seed. The rounds alternate between the versions, so a busy machine slows both
alike; the script prints each round, the median iterations per second of each and
their ratio, and whether the two results agree (the same seed gives the same
field when the code computes the same thing; Dr.Jit on one thread makes it
deterministic).

    python benchmarks/reconstruction.py --baseline /path/to/other/checkout
    git worktree add /tmp/before HEAD~5 && python benchmarks/reconstruction.py --baseline /tmp/before

Without ``--baseline`` it measures this checkout alone.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]

WORKER = r"""
import json, sys, warnings
import drjit as dr
import mi_nest
from mi_nest.dataset import SimulationSettings, simulate
args = json.loads(sys.argv[1])
dr.set_thread_count(args["threads"])
warnings.simplefilter("ignore")
settings = SimulationSettings(azimuths=args["rotations"], elevations=args["rotations"], res=args["res"],
                              spp=args["spp"])
simulate(args["scene"], args["data"], settings, defines=args["defines"], progress=False)
scene = mi_nest.load_scene(args["scene"], res=args["res"], **args["defines"])
# Every option the defaults of some version changed is given: the two versions run the same configuration.
result = mi_nest.optimize(scene, args["data"], iterations=args["iterations"], kind="grid",
                          resolution=args["resolution"], batch_size=args["batch_size"], learning_rate=0.03,
                          final_learning_rate=0.003, smoothness=0.0, smoothness_edge=None, average_last=0.0, seed=0,
                          progress=False)
print(json.dumps({"seconds": result.seconds, "iterations": len(result.history),
                  "loss": result.history[-1]["loss"], "error": result.metrics.get("deviatoric_error"),
                  "mi_nest": mi_nest.__file__}))
"""


def cpu_name():
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return "unknown CPU"
    name = next((line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")), "unknown CPU")
    flags = next((line for line in lines if line.startswith("flags")), "")
    return f"{name} ({'AVX-512' if 'avx512f' in flags else 'AVX2' if 'avx2' in flags else 'no AVX2'})"


def installed_layout(tree: Path, into: Path) -> Path:
    """``tree``'s package laid out as its wheel installs it, in ``into``; returns the folder for PYTHONPATH."""
    if not (tree / "mi_nest").is_dir():
        raise SystemExit(f"{tree} is not an mi_nest checkout (no mi_nest/ in it)")
    package = into / "mi_nest"
    ignore = shutil.ignore_patterns("__pycache__")
    shutil.copytree(tree / "mi_nest", package, ignore=ignore)
    shutil.copytree(tree / "plugins", package / "plugins", ignore=ignore)
    shutil.copytree(tree / "scenes", package / "scenes", ignore=ignore)
    return into


def run(path_entry: Path, options: dict, worker: str = WORKER) -> dict:
    """``worker`` run on the copy of one version at ``path_entry`` with ``options``: the JSON it prints last."""
    env = {**os.environ, "PYTHONPATH": str(path_entry)}
    done = subprocess.run([sys.executable, "-c", worker, json.dumps(options)], env=env, capture_output=True,
                          text=True, cwd=path_entry)
    if done.returncode != 0:
        raise SystemExit(f"the run from {path_entry} failed:\n{done.stderr[-3000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    if not result["mi_nest"].startswith(str(path_entry)):
        raise SystemExit(f"the run imported {result['mi_nest']}, not the copy in {path_entry}")
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="another mi_nest checkout to compare with (e.g. a git worktree)")
    parser.add_argument("--scene", default="disk_compression")
    parser.add_argument("-D", dest="defines", action="append", default=["load=100", "contact_width=4"],
                        metavar="NAME=VALUE", help="scene defines (default: load=100, contact_width=4)")
    parser.add_argument("--rotations", type=int, default=8, help="azimuths and elevations (default: 8)")
    parser.add_argument("--res", type=int, default=32, help="image width and height (default: 32)")
    parser.add_argument("--iterations", type=int, default=500)
    parser.add_argument("--resolution", type=int, default=16, help="grid nodes along the longest axis")
    parser.add_argument("--batch-size", type=int, default=2048)
    parser.add_argument("--spp", type=int, default=1,
                        help="samples per pixel simulated: the rays per pixel the fit averages, up to 4 (default: 1)")
    parser.add_argument("--rounds", type=int, default=3, help="alternating runs of each version (default: 3)")
    parser.add_argument("--threads", type=int, default=1, help="Dr.Jit threads (default 1: deterministic)")
    args = parser.parse_args()
    defines = dict(d.split("=", 1) for d in args.defines)

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        versions = {"this checkout": installed_layout(HERE, tmp / "current")}
        if args.baseline:
            versions["baseline"] = installed_layout(args.baseline.resolve(), tmp / "baseline")
        print(f"{cpu_name()}; {args.scene} {defines}, {args.rotations}x{args.rotations} rotations at "
              f"{args.res}x{args.res}, grid {args.resolution}, {args.iterations} iterations of {args.batch_size} "
              f"pixels x {min(args.spp, 4)} rays, {args.threads} Dr.Jit thread(s)")
        results = {name: [] for name in versions}
        for round_ in range(args.rounds):
            # alternate who goes first: the first run of a round may pay for kernels the second finds cached
            for name, path_entry in list(versions.items())[::1 if round_ % 2 == 0 else -1]:
                options = dict(vars(args), defines=defines, data=str(tmp / f"data-{name.replace(' ', '_')}"))
                options.pop("baseline")
                result = run(path_entry, options)
                results[name].append(result)
                print(f"round {round_ + 1} {name:13s} {result['iterations'] / result['seconds']:7.1f} it/s  "
                      f"loss {result['loss']:.7f}  error {100 * (result['error'] or 0):.4f}%")
        speed = {name: statistics.median(r["iterations"] / r["seconds"] for r in runs) for name, runs in results.items()}
        for name, value in speed.items():
            print(f"median {name}: {value:.1f} it/s")
        if args.baseline:
            print(f"ratio this checkout / baseline: {speed['this checkout'] / speed['baseline']:.3f}")
            same = all(a["loss"] == b["loss"] and a["error"] == b["error"]
                       for a, b in zip(results["this checkout"], results["baseline"]))
            print("results: identical (loss and error, every round)" if same else
                  "results: DIFFER between the versions (expected only when the code computes something else)")


if __name__ == "__main__":
    main()
