"""Branch repair on finished results: the refill alone, then a run from it against one from the result as it was.

For each result directory (a ``mi-nest reconstruct`` output of a simulated dataset), as a run's own repair does
(``mi_nest.reconstruct.repair``): the imbalance, the region it marks, the error before and after the harmonic
refill; then ``mi-nest reconstruct DATA --start X --minutes M --option branch_repair=0`` from the refilled field
and from the result as it was, for the same minutes with no repair inside the runs, and the errors they end at.

    .venv/bin/python experiments/branch_repair.py experiments/out/load_series/disk_300N_90deg/low --minutes 3

Writes ``experiments/results/branch_repair.csv`` (a row per result) and prints the CPU.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import common

import mi_nest  # noqa: F401  (sets the variant)
from mi_nest.reconstruct import Reconstruction, metrics
from mi_nest.reconstruct.repair import refill as refilled_nodes
from mi_nest.reconstruct.trust import imbalance
from mi_nest.scene import specimen_shapes

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
from accuracy_suite import read_rows, run_command  # noqa: E402
from reconstruction import cpu_name  # noqa: E402


def refill(directory: Path, output: Path) -> dict:
    """``directory``'s field refilled where its imbalance encloses a region, saved in ``output``; what it did."""
    result = Reconstruction.load(directory)
    dataset, scene, truth = common.simulated_from(result)
    probe = metrics.ErrorProbe(truth, metrics.evaluation_points(scene, specimen_shapes(scene)))
    field = result.field
    if field.kind != "grid":
        raise SystemExit(f"{directory}: a {field.kind} field; branch repair refills grids only")
    before = probe(field)
    nodes, share, regions = refilled_nodes(field.nodes(), imbalance(scene, field, field.shape))
    field.set_nodes(nodes)
    result.save(output)
    return {"dataset": str(dataset.directory), "error": round(before, 4), "regions": regions,
            "share": round(share, 4), "refilled_error": round(probe(field), 4)}


def run_from(start: Path, data: str, output: Path, minutes: float) -> dict:
    run_command("reconstruct", [data, "-o", str(output), "--start", str(start), "--minutes", f"{minutes:g}",
                                "--restart", "--allow-aliased", "--no-progress", "--option", "branch_repair=0"])
    record = json.loads((output / "reconstruction.json").read_text())
    return {"error": round(record["metrics"]["deviatoric_error"], 4), "iterations": len(record["history"]),
            "loss": round(record["history"][-1]["loss"], 5)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="+", type=Path, help="mi-nest reconstruct output directories")
    parser.add_argument("--minutes", type=float, default=3.0, help="of each run from the two starts")
    parser.add_argument("--output", type=Path, default=HERE / "experiments" / "out" / "branch_repair")
    args = parser.parse_args()
    table = HERE / "experiments" / "results" / "branch_repair.csv"
    rows = read_rows(table)
    print(f"CPU: {cpu_name()}", flush=True)
    for directory in args.results:
        name = f"{directory.parent.name}_{directory.name}"
        refilled = refill(directory, args.output / name / "refilled")
        ran = {label: run_from(start, refilled["dataset"], args.output / name / f"from_{label}", args.minutes)
               for label, start in (("refilled", args.output / name / "refilled"), ("result", directory))}
        row = {"result": name, "error": refilled["error"], "regions": refilled["regions"],
               "refilled_share": refilled["share"], "refilled_error": refilled["refilled_error"],
               "minutes": args.minutes, **{f"from_{label}_{key}": value for label, run in ran.items()
                                           for key, value in run.items()}, "cpu": cpu_name()}
        rows = [r for r in rows if r["result"] != name] + [row]
        print(json.dumps(row), flush=True)
        common.write_table(rows, table)


if __name__ == "__main__":
    main()
