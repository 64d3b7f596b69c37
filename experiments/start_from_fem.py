"""A start for dense fringes: reconstructions started from an FEM-like model of the part at a wrong load.

The accuracy suite's dense-fringe misses are local minima (``loss_landscape.py``): from zero the coarse stages
choose a fringe order and keep it. An engineer usually has a model of the part; its load is rarely exact. Each
case here exports the scene's own field as a 3D-TSV file (what an FEM model would give: ``mi-nest export SCENE
-D ... -o model.TSV``), its stress times ``factor`` (in linear elasticity, the model at that factor of the load;
the disks' results committed first were exported at that load, the same field), and reconstructs the accuracy
suite's dataset from it (``start=``), as given or first scaled to the load factor the training views prefer
(``start_scale_range``), beside the same run from zero, for the same time. Writes ``start_from_fem.csv`` (the
start's own error and the result's) and ``.png``:

    .venv/bin/python experiments/start_from_fem.py --cases disk_600N --factors 1,0.95,0.9,0.8 --scale-ranges 0 \
        --minutes 3 --name start_from_fem_given
    .venv/bin/python experiments/start_from_fem.py --cases disk_600N --factors 0.9,0.8 --scale-ranges 0.3,0 \
        --minutes 3

The datasets are the accuracy suite's (``benchmarks/accuracy_suite.py``, simulated there first).
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import common
from mi_nest.cli import main as mi_nest_main
from mi_nest.io.tsv import read_stress_file, write_stress_file

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
from accuracy_suite import CASES, dataset_directory, read_rows, reconstruct  # noqa: E402
from reconstruction import cpu_name  # noqa: E402

SUITE = HERE / "experiments" / "out" / "accuracy_suite"
ZERO = "zero"


def start_file(case, factor: float, directory: Path) -> Path:
    """The case's scene field (with the case's defines) exported as a 3D-TSV model of the part, its stress times
    ``factor``: in linear elasticity, the model at ``factor`` times the load."""
    model = directory / f"{case.name}_model.TSV"
    if not model.is_file():
        directory.mkdir(parents=True, exist_ok=True)
        arguments = ["export", case.scene, "-o", str(model)]
        for name, value in case.defines.items():
            arguments += ["-D", f"{name}={value}"]
        if mi_nest_main(arguments) != 0:
            raise SystemExit(f"could not export the scene field of {case.name}")
    if factor == 1.0:
        return model
    path = directory / f"{case.name}_model_x{factor:g}.TSV"
    if not path.is_file():
        read = read_stress_file(model)
        write_stress_file(path, read.vertices, read.elements, factor * read.stress, read.node_forces,
                          read.fixed_nodes, note=f"{case.name}'s scene field times {factor:g}")
    return path


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="disk_600N", help="accuracy suite cases")
    parser.add_argument("--factors", default="1,0.95,0.9,0.8", help="start loads, as factors of the true load")
    parser.add_argument("--minutes", type=float, default=3.0, help="of optimisation per run")
    parser.add_argument("--scale-ranges", default="0.3",
                        help="start_scale_range of each start: 0 takes the model as given, R scales it to the load "
                             "factor within 1 +- R that fits the training views best")
    parser.add_argument("--no-zero", action="store_true", help="skip the run from zero")
    parser.add_argument("--output", type=Path, default=HERE / "experiments" / "out" / "start_from_fem")
    parser.add_argument("--name", default="start_from_fem", help="of the CSV and PNG in experiments/results")
    args = parser.parse_args()
    by_name = {case.name: case for case in CASES}
    unknown = [name for name in args.cases.split(",") if name not in by_name]
    if unknown:
        raise SystemExit(f"not accuracy suite cases: {unknown}")
    factors = ([] if args.no_zero else [ZERO]) + [float(f) for f in args.factors.split(",")]
    ranges = [float(r) for r in args.scale_ranges.split(",")]
    table = HERE / "experiments" / "results" / f"{args.name}.csv"
    # A rerun adds its cases to the table; a run of a case and start that the table has replaces that row.
    rows = read_rows(table)
    print(f"CPU: {cpu_name()}", flush=True)
    for name in args.cases.split(","):
        case = by_name[name]
        data = dataset_directory(case, SUITE, case.rotations, case.res)
        if not (data / "dataset.json").is_file():
            raise SystemExit(f"{data} is missing: run python benchmarks/accuracy_suite.py --cases {name} first")
        for factor, spread in [(f, r) for f in factors for r in ranges]:
            if factor == ZERO and spread != ranges[0]:
                continue
            flags = () if factor == ZERO else ("--start", str(start_file(case, factor, args.output / "starts")),
                                                "--option", f"start_scale_range={spread:g}")
            label = f"{name} from {ZERO}" if factor == ZERO else f"{name} from {factor:g} x load" + (
                f", scaled within {spread:g}" if spread else ", as given")
            output = args.output / "results" / label.replace(" ", "_").replace(",", "")
            record = reconstruct(replace(case, flags=case.flags + flags), data, output, args.minutes, 200)["record"]
            history = record["history"]
            row = {"case": name, "start": factor if factor == ZERO else f"{factor:g} x load",
                   "scale_range": "" if factor == ZERO else str(spread), "label": label,
                   "start_factor": history[0].get("start_factor", ""),
                   "start_error": round(history[0]["deviatoric_error"], 4),
                   "deviatoric_error": round(record["metrics"]["deviatoric_error"], 4),
                   "test_psnr": round(record["metrics"]["test_psnr"], 2), "iterations": len(history),
                   "optimise_s": round(record["seconds"], 1), "minutes": args.minutes, "cpu": cpu_name()}
            rows = [r for r in rows if r["label"] != label] + [row]
            print(json.dumps(row), flush=True)
            common.write_table(rows, table)
            chart(rows, args.output / "results", table.with_suffix(".png"),
                  f"starts from a model of the part at a wrong load ({cpu_name()})")


def chart(rows: list[dict], results: Path, path: Path, title: str) -> None:
    """Error against optimisation time, a line per row (its run's history, read back from its output)."""
    plt = common.pyplot()
    figure, axis = plt.subplots(figsize=(8, 5))
    for row in rows:
        record = results / row["label"].replace(" ", "_").replace(",", "") / "reconstruction.json"
        if not record.is_file():
            continue
        points = [(h["seconds"], h["deviatoric_error"]) for h in json.loads(record.read_text())["history"]
                  if "deviatoric_error" in h]
        axis.plot(*zip(*points), lw=1.0, ls="--" if ZERO in row["label"] else "-",
                  label=f"{row['label']} ({row['minutes']} min)")
    axis.set(xlabel="optimisation time (s)", ylabel="relative deviatoric stress error", yscale="log", title=title)
    axis.axhline(0.15, color="grey", lw=0.6, ls=":")
    axis.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


if __name__ == "__main__":
    main()
