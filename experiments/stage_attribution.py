"""Which coarse-to-fine stage chooses the branch? The defaults' run with one stage started from the truth's best grid.

A grid run from zero climbs a ladder of grids (8, 16, 32 nodes along the longest axis, then the final grid). Here the
run is the defaults' (as ``mi-nest reconstruct DATA -o OUT --minutes M``), except that when the stage of ``--nodes``
nodes begins, its grid is replaced by the grid of that size that fits the truth best (least squares on a lattice
three times finer than the evaluation points) and Adam starts afresh, as at any stage. Where the run then ends near
the truth's best final grid, every stage from there on holds the right basin, and the branch was chosen before
it; where it ends where the run from zero does, that stage leaves the truth's basin itself. ``--nodes 0`` plants
nothing: the control. Writes ``experiments/results/stage_attribution.csv`` (a row per case and planted stage,
replacing the same one's earlier row): the error when the stage began and at the end of each stage, at the end,
the held-out PSNR:

    .venv/bin/python experiments/stage_attribution.py --case disk_300N --nodes 16

The dataset is the accuracy suite's (``benchmarks/accuracy_suite.py``, simulated there first).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import common

import mi_nest
from mi_nest.dataset import Dataset
from mi_nest.dataset.truth import recorded_truth
from mi_nest.reconstruct import loop, metrics, optimization
from mi_nest.scene import specimen_shapes

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
from accuracy_suite import CASES, dataset_directory, read_rows, simulate  # noqa: E402
from reconstruction import cpu_name  # noqa: E402

SUITE = HERE / "experiments" / "out" / "accuracy_suite"
TRACK_EVERY = 200


def planted_run(truth, fit_points, nodes: int) -> type[loop.Run]:
    """A :class:`~mi_nest.reconstruct.loop.Run` whose stage of ``nodes`` nodes begins at the truth's best grid of
    that size (``truth`` fitted at ``fit_points``); what it planted, and when, goes into ``planted``, its ladder into
    ``ladder``. A ``nodes`` (not 0) that is no stage of the ladder is refused before the run starts."""

    class PlantedRun(loop.Run):
        planted, ladder = {}, []

        def __init__(self, *arguments, **options):
            super().__init__(*arguments, **options)
            PlantedRun.ladder[:] = self.stages
            resolutions = [r for _, r in self.stages]
            if nodes and nodes not in resolutions:
                raise SystemExit(f"no stage of {nodes} nodes in this run's ladder {resolutions}: give one of them, "
                                 "or 0")
            self._plant_if_due()

        def _refine_if_due(self) -> None:
            super()._refine_if_due()
            self._plant_if_due()

        def _plant_if_due(self) -> None:
            if PlantedRun.planted or self.field.config.resolution != nodes:
                return
            self.field.set_nodes(metrics.fitted_nodes(self.field, truth, fit_points))
            self.optimizer = self._optimizer()
            PlantedRun.planted.update(seconds=round(self.seconds, 1), shape="x".join(map(str, self.field.shape)))
            print(f"planted the truth's best {PlantedRun.planted['shape']} grid at {self.seconds:.0f} s", flush=True)

    return PlantedRun


def stage_ends(history: list[dict], stages: list[tuple[float, int]], seconds: float) -> dict:
    """The tracked error at the end of each stage of ``stages`` (the last record before the next begins) in a run
    of ``seconds``."""
    tracked = [h for h in history if "deviatoric_error" in h]
    ends = {}
    for (_, resolution), following in zip(stages, [s for s, _ in stages[1:]] + [1.0]):
        before = [h for h in tracked if h["seconds"] <= following * seconds]
        if before:
            ends[f"error_end_{resolution}"] = round(before[-1]["deviatoric_error"], 4)
    return ends


def suite_dataset(case):
    """The accuracy suite's dataset of ``case`` (simulated first if missing), its scene and its true field; a case
    that runs with options of its own is refused, as these runs are the defaults' with one change."""
    if case.flags:
        raise SystemExit(f"{case.name} runs with {' '.join(case.flags)}: give a case of the defaults alone")
    data = dataset_directory(case, SUITE, case.rotations, case.res)
    simulate(case, data, case.rotations, case.res)
    dataset = Dataset(data)
    scene, truth = recorded_truth(dataset)
    return dataset, scene, truth


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    by_name = {case.name: case for case in CASES}
    parser.add_argument("--case", default="disk_300N", choices=sorted(by_name), metavar="CASE",
                        help="an accuracy suite case (default: disk_300N)")
    parser.add_argument("--nodes", type=int, default=16,
                        help="nodes along the longest axis of the stage to plant (0: none, the control; default 16)")
    parser.add_argument("--minutes", type=float, default=10.0, help="of the whole run (default: 10)")
    parser.add_argument("--output", type=Path, default=HERE / "experiments" / "out" / "stage_attribution")
    args = parser.parse_args()
    if not args.minutes > 0:
        raise SystemExit(f"--minutes must be positive, got {args.minutes:g}")
    case = by_name[args.case]
    dataset, scene, truth = suite_dataset(case)
    fit_points = metrics.evaluation_points(scene, specimen_shapes(scene), 3 * metrics.EVALUATION_POINTS)
    run_class = planted_run(truth, fit_points, args.nodes)
    print(f"CPU: {cpu_name()}", flush=True)
    optimization.Run = run_class
    output = args.output / f"{case.name}_planted{args.nodes}"
    result = mi_nest.optimize(scene, dataset, output=output, resume=False, progress=False,
                              time_limit=60.0 * args.minutes, iterations=10 ** 9, track_error_every=TRACK_EVERY)
    tracked = [h for h in result.history if "deviatoric_error" in h]
    at_plant = [h for h in tracked if h["seconds"] >= run_class.planted.get("seconds", 0.0)]
    row = {"case": case.name, "planted_nodes": args.nodes, "planted_grid": run_class.planted.get("shape", ""),
           "planted_at_s": run_class.planted.get("seconds", ""),
           "error_at_plant": round(at_plant[0]["deviatoric_error"], 4) if args.nodes and at_plant else "",
           **stage_ends(result.history, run_class.ladder, 60.0 * args.minutes),
           "deviatoric_error": round(result.metrics["deviatoric_error"], 4),
           "test_psnr": round(result.metrics["test_psnr"], 2), "iterations": len(result.history),
           "minutes": args.minutes, "cpu": cpu_name()}
    table = HERE / "experiments" / "results" / "stage_attribution.csv"
    rows = [r for r in read_rows(table) if (r["case"], r["planted_nodes"]) != (case.name, str(args.nodes))]
    common.write_table(rows + [row], table)
    print(row, flush=True)


if __name__ == "__main__":
    main()
