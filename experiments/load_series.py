"""A load series against dense fringes: reconstruct the part at a low load, then start the test load from it.

Photoelasticians count fringe orders by watching them appear as the load rises. The same holds here: at a low
load the fringes are sparse and a descent from zero finds the field; in linear elasticity the stress at the test
load is that field times the ratio of the loads (which the load cell gives), and a run started there
(``--start LOW_RESULT --option start_load_ratio=R``, the factor then scanned within 30% of it) is in the right
basin where a descent from zero stays on a wrong branch (``loss_landscape.py``). Each case is an accuracy suite
case (its dataset, shared with the suite) and the same part at a lower load, simulated as the suite simulates
(fixed seeds, read noise 0.01); the low load is reconstructed for ``--low-minutes`` and the test load for the
rest of ``--minutes``, so the series takes the suite's budget in all. Writes ``load_series.csv`` (with the suite's
row from zero beside it, when ``accuracy_suite.csv`` has it) and ``load_series.png``:

    .venv/bin/python experiments/load_series.py --cases disk_600N,stacked_disks --minutes 10 --low-minutes 4
    .venv/bin/python experiments/load_series.py --cases disk_600N,stacked_disks --seed 1

The kitten scene has no load: its low load is simulated as three times its fringe value, which gives the images
a third of the load would. Its reconstruction is then the test load's stress already (ratio 1).
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import common

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
from accuracy_suite import CASES, dataset_directory, read_rows, reconstruct, simulate  # noqa: E402
from reconstruction import cpu_name  # noqa: E402

SUITE = HERE / "experiments" / "out" / "accuracy_suite"


@dataclass(frozen=True)
class Series:
    """The suite case ``case`` reached from the same part under ``low`` (its defines changed so): the start is
    multiplied by ``ratio``, the test load over the low one as the stress sees it."""
    case: str
    low: dict
    ratio: float
    name: str = ""
    from_zero: str = ""     # the suite's row of the run from zero under today's defaults, where not ``case``
    started: tuple = ()     # the test load's own options

    @property
    def label(self) -> str:
        return self.name or self.case


# The disks keep their 4 mm contacts at every load; a real contact widens with the load, as its square root in
# Hertz's theory: disk_600N_hertz starts from 100 N over 4 * sqrt(100 / 600) = 1.63 mm, a field that is not the
# test's scaled.
SERIES = {s.label: s for s in [
    Series("disk_600N", {"load": 100}, 6.0),
    Series("disk_600N", {"load": 100, "contact_width": 1.63}, 6.0, name="disk_600N_hertz"),
    Series("disk_300N", {"load": 100}, 3.0, from_zero="disk_300N_relative05"),
    Series("stacked_disks", {"load": 100}, 3.0),
    Series("disk_300N_90deg", {"load": 100}, 3.0),
    # From zero, two of four seeds end on a strip along the bore (the suite's lame_cylinder_seed1/3).
    Series("lame_cylinder", {"pressure": 0.5}, 4.0),
    Series("lame_cylinder", {"pressure": 1.0}, 2.0, name="lame_cylinder_half"),
    Series("disk_1kN_256px", {"load": 200}, 5.0),
    # From 200 N the 256-px disk's low load ended at 15.3% (2% of its pixels aliased): a tenth of the load instead.
    Series("disk_1kN_256px", {"load": 100}, 10.0, name="disk_1kN_256px_from100N"),
    Series("kitten_air", {"fringe_value": 13500}, 1.0),
    # A started kitten in air left its start at the descent's rate (docs/reconstruction.md, "A start from a model"):
    # this case's rate is now every started run's default; the rows in results/load_series.csv before 2026-11-28's
    # twelfth session ran at the descent's 0.05 (kitten_air: 17.6%).
    Series("kitten_air", {"fringe_value": 13500}, 1.0, name="kitten_air_rate0.005",
           started=("--option", "learning_rate=0.005")),
]}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(SERIES), help=f"of {', '.join(SERIES)}")
    parser.add_argument("--minutes", type=float, default=10.0, help="of optimisation per case, both loads together")
    parser.add_argument("--low-minutes", type=float, default=4.0, help="of them on the low load")
    parser.add_argument("--output", type=Path, default=HERE / "experiments" / "out" / "load_series")
    parser.add_argument("--seed", type=int, default=0, help="of both runs (the optimiser's batches); not 0: the "
                                                           "rows are named CASE_seedN")
    parser.add_argument("--name", default="load_series", help="of the CSV and PNG in experiments/results")
    args = parser.parse_args()
    unknown = [name for name in args.cases.split(",") if name not in SERIES]
    if unknown:
        raise SystemExit(f"no load series for {unknown}: give some of {', '.join(SERIES)}")
    if not 0 < args.low_minutes < args.minutes:
        raise SystemExit(f"--low-minutes must lie between 0 and --minutes ({args.minutes:g}), got {args.low_minutes:g}")
    suite = {row["case"]: row for row in read_rows(HERE / "experiments" / "results" / "accuracy_suite.csv")}
    table = HERE / "experiments" / "results" / f"{args.name}.csv"
    rows = read_rows(table)
    print(f"CPU: {cpu_name()}", flush=True)
    by_name = {case.name: case for case in CASES}
    for name in args.cases.split(","):
        series = SERIES[name]
        case = by_name[series.case]
        seeded = ("--option", f"seed={args.seed}") if args.seed else ()
        low_case = replace(case, name=f"{name}_low", defines={**case.defines, **series.low}, flags=seeded)
        high_data = dataset_directory(case, SUITE, case.rotations, case.res)
        low_data = dataset_directory(replace(case, name=name), SUITE, case.rotations, case.res, "_low")
        simulate(case, high_data, case.rotations, case.res)
        simulate(low_case, low_data, case.rotations, case.res)
        name = f"{name}_seed{args.seed}" if args.seed else name
        low_out, high_out = args.output / name / "low", args.output / name / "test_load"
        low = reconstruct(low_case, low_data, low_out, args.low_minutes, 200)["record"]
        started = replace(case, flags=case.flags + seeded + series.started + (
            "--start", str(low_out), "--option", f"start_load_ratio={series.ratio:g}"))
        high = reconstruct(started, high_data, high_out, args.minutes - args.low_minutes, 200)["record"]
        history = high["history"]
        # A seeded series against the suite's run from zero with the same seed, where the suite has one.
        same_seed = f"{series.case}_seed{args.seed}" if args.seed and not series.from_zero else None
        zero = suite.get(same_seed) or suite.get(series.from_zero or series.case, {})
        row = {"case": name, "suite_case": series.case, "test_load_options": " ".join(series.started),
               "defines": " ".join(f"{k}={v}" for k, v in case.defines.items()),
               "low": " ".join(f"{k}={v}" for k, v in series.low.items()), "ratio": series.ratio,
               "low_error": round(low["metrics"]["deviatoric_error"], 4), "low_iterations": len(low["history"]),
               "start_factor": history[0].get("start_factor", ""),
               "start_error": round(history[0]["deviatoric_error"], 4),
               "deviatoric_error": round(high["metrics"]["deviatoric_error"], 4), "iterations": len(history),
               "test_psnr": round(high["metrics"]["test_psnr"], 2),
               "minutes": args.minutes, "low_minutes": args.low_minutes,
               "from_zero_in_suite": zero.get("deviatoric_error", ""), "target": case.target, "cpu": cpu_name()}
        rows = [r for r in rows if r["case"] != name] + [row]
        print(json.dumps(row), flush=True)
        common.write_table(rows, table)
        chart(rows, args.output, table.with_suffix(".png"), f"load series ({cpu_name()})")


def chart(rows: list[dict], output: Path, path: Path, title: str) -> None:
    """Error against optimisation time, the low load's run then the test load's, a line per case."""
    plt = common.pyplot()
    figure, axis = plt.subplots(figsize=(8, 5))
    for row in rows:
        offset, points = 0.0, []
        for part in ("low", "test_load"):
            record = output / row["case"] / part / "reconstruction.json"
            if not record.is_file():
                break
            read = json.loads(record.read_text())
            final = row["low_error" if part == "low" else "deviatoric_error"]
            if round(read["metrics"]["deviatoric_error"], 4) != float(final):
                # Another table's run of the same case wrote over this row's (load_series vs _started_rate).
                points = []
                break
            if part == "test_load":
                points.append((offset, float("nan")))
            points += [(offset + h["seconds"], h["deviatoric_error"]) for h in read["history"]
                       if "deviatoric_error" in h]
            offset += read["seconds"]
        label = f"{row['case']} (ratio {row['ratio']})"
        if points:
            line, = axis.plot(*zip(*points), lw=1.0, label=label)
        else:
            # A row from an earlier run whose output is gone: its two ends, where each load's run stopped.
            line, = axis.plot([60 * float(row["low_minutes"]), 60 * float(row["minutes"])],
                              [float(row["low_error"]), float(row["deviatoric_error"])], ls=":", marker="o", ms=3,
                              lw=0.8, label=f"{label}, ends only")
        if row.get("from_zero_in_suite"):
            axis.axhline(float(row["from_zero_in_suite"]), color=line.get_color(), lw=0.6, ls="--")
    axis.set(xlabel="optimisation time, low load then test load (s)", ylabel="relative deviatoric stress error",
             yscale="log", title=title)
    axis.axhline(0.15, color="grey", lw=0.6, ls=":")
    axis.legend(fontsize=7)
    figure.text(0.01, 0.01, "dashed: the accuracy suite's run from zero at the test load; dotted: rows whose run "
                "histories were not kept, their low load's and test load's final errors", fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


if __name__ == "__main__":
    main()
