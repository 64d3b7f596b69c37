"""Why a reconstruction missed: the data's loss on the straight line from the result to the truth.

For each finished grid reconstruction of a simulated dataset (``mi-nest reconstruct`` output directories, such as
the accuracy suite's), the fields ``(1 - t) R + t T`` between the result ``R`` and ``T``, the grid of the same
size that fits the truth best (least squares on a lattice three times finer than the evaluation points), are
scored at ``t`` from 0 to 1: the mean L1 error of the 16 intensities on training and held-out views (each
pixel averaged over 16 stratified rays, as the camera integrates it), the smoothness penalty at the run's final
weight, the relative deviatoric error, and the mean squared equilibrium residual ``div(s) + grad(p)`` that the
best mean stress leaves (stress scales per box length, squared) over the grid's cells inside the part, over all of
them and with the largest twentieth left out (where a grid cannot balance even the truth: contacts, singular
loads). Read off it:

- ``T``'s error: what this grid could reach at best (the representation's floor); where it keeps half the
  result's error or more, the verdict is ``floor``;
- the data loss at ``T`` against ``R``: whether the images tell the truth from the result at all. Where not
  (``unresolved``), the error left is what these data do not resolve;
- where they do, the highest loss on the way: a ridge above ``R`` makes it a local minimum that a descent does not
  leave (``ridge``); none means that a longer or better-stepped descent gets there (``open``).

    python experiments/loss_landscape.py experiments/out/accuracy_suite/accuracy_suite/disk_300N ...

Writes ``experiments/results/loss_landscape.csv`` (a row per case and ``t``, with the case's verdict) and
``.png``; prints the verdicts, the CPU and the seconds each case took.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import common
import numpy as np

import mi_nest  # noqa: F401  (sets the variant)
from mi_nest.reconstruct import Reconstruction, equilibrium, metrics
from mi_nest.reconstruct.evaluation import SampledViewLoss
from mi_nest.scene import specimen_shapes

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from reconstruction import cpu_name  # noqa: E402

HERE = Path(__file__).resolve().parents[1]
STEPS = np.linspace(0.0, 1.0, 11)
# A loss difference smaller than this share of the loss at the result is read as none (the views are a sample).
TIE = 0.02
# Where the truth's best grid keeps this share of the result's error, most of that error is the grid's.
FLOOR_SHARE = 0.5
# The share of cells with the largest equilibrium residual that the trimmed residual leaves out.
EQUILIBRIUM_TRIM = 0.05


def landscape(directory: Path, views: int, samples: int) -> tuple[list[dict], str]:
    result = Reconstruction.load(directory)
    field = result.field
    if field.kind != "grid":
        raise SystemExit(f"{directory}: a {field.kind} field; the line to the truth is drawn between grids only")
    dataset, scene, truth = common.simulated_from(result)
    shapes = specimen_shapes(scene)
    start = time.perf_counter()
    points = metrics.evaluation_points(scene, shapes)
    error_of = metrics.ErrorProbe(truth, points)
    best = metrics.fitted_nodes(field, truth, metrics.evaluation_points(scene, shapes, 3 * metrics.EVALUATION_POINTS))
    found = field.nodes()
    tracer = result.tracer(scene)
    mask = result.config.optimiser.mask
    train = SampledViewLoss(scene, dataset, tracer, mask, "train", views, samples)
    test = SampledViewLoss(scene, dataset, tracer, mask, "test", views, samples)
    regulariser = result.config.regulariser
    balance = equilibrium.MeanStressSolver(equilibrium.specimen_stencil(scene, field.shape, field.bbox_min,
                                                                        field.bbox_max))
    rows = []
    for t in STEPS:
        field.set_nodes((1.0 - t) * found + t * best)
        rms = field.rms() if regulariser.relative_to is not None else None
        penalty = field.smoothness_penalty(regulariser.smoothness_at(1.0, rms), regulariser.edge_at(rms))
        rows.append({"case": directory.name, "t": round(float(t), 2), "deviatoric_error": round(error_of(field), 4),
                     "train_loss": round(train(field), 5), "test_loss": round(test(field), 5),
                     "smoothness": round(float(penalty[0]) if penalty is not None else 0.0, 6),
                     **imbalance(field, balance)})
    exact = {"case": directory.name, "t": "truth", "deviatoric_error": 0.0, "train_loss": round(train(truth), 5),
             "test_loss": round(test(truth), 5), "smoothness": float("nan"), "equilibrium": float("nan"),
             "equilibrium_trimmed": float("nan")}
    seconds = time.perf_counter() - start
    found_verdict = verdict(rows)
    for row in rows + [exact]:
        row.update(verdict=found_verdict, views=f"{len(train.positions)} train, {len(test.positions)} held out",
                   pixel_samples=samples, seconds=round(seconds, 1), cpu=cpu_name())
    return rows + [exact], explain(rows, exact)


def imbalance(field, solver: equilibrium.MeanStressSolver) -> dict:
    """The grid's mean squared equilibrium residual over the cells inside the part, and with the
    :data:`EQUILIBRIUM_TRIM` largest left out."""
    squared = solver.cell_residuals(np.array(field.texture.tensor(), dtype=np.float64))
    clipped = np.sort(squared)[:len(squared) - int(EQUILIBRIUM_TRIM * len(squared))]
    return {"equilibrium": round(float(squared.mean()), 3), "equilibrium_trimmed": round(float(clipped.mean()), 3)}


VERDICTS = {
    "floor": "the truth's best grid of this size keeps half the result's error or more: the error is mostly the "
             "representation's (a finer grid would lower it)",
    "unresolved": "the result explains these images as well as the truth's grid: the error left is what these data "
                  "do not resolve (more views, pixels or a prior would lower it, not more iterations)",
    "ridge": "the data prefer the truth's grid, behind a ridge above the result: a local minimum that a descent does "
             "not leave (a better start would lower it)",
    "open": "the data prefer the truth's grid and the way down is open: the optimiser fell short (more iterations or "
            "better steps would lower it)",
}


def verdict(rows: list[dict]) -> str:
    """Which of :data:`VERDICTS` the line from the result (``rows[0]``) to the truth's grid (``rows[-1]``) shows."""
    at_result, at_best = rows[0], rows[-1]
    tie = TIE * at_result["train_loss"]
    if at_best["deviatoric_error"] >= FLOOR_SHARE * at_result["deviatoric_error"]:
        return "floor"
    if at_best["train_loss"] > at_result["train_loss"] - tie:
        return "unresolved"
    barrier = max(r["train_loss"] for r in rows) - at_result["train_loss"]
    return "ridge" if barrier > tie else "open"


def explain(rows: list[dict], exact: dict) -> str:
    at_result, at_best = rows[0], rows[-1]
    barrier = max(r["train_loss"] for r in rows) - at_result["train_loss"]
    lines = [f"{at_result['case']}: error {100 * at_result['deviatoric_error']:.1f}% (the best grid of this size: "
             f"{100 * at_best['deviatoric_error']:.1f}%); training loss {at_result['train_loss']:.4f} at the result, "
             f"{at_best['train_loss']:.4f} at the best grid, {exact['train_loss']:.4f} at the exact truth, "
             f"highest on the way {barrier:+.4f} above the result",
             f"  {VERDICTS[at_result['verdict']]}"]
    lines.append(f"  equilibrium residual (mean square over the part's cells): {at_result['equilibrium']:.4g} at the "
                 f"result, {at_best['equilibrium']:.4g} at the best grid; without the largest "
                 f"{EQUILIBRIUM_TRIM:.0%} of cells {at_result['equilibrium_trimmed']:.4g} and "
                 f"{at_best['equilibrium_trimmed']:.4g}")
    objective = [r["train_loss"] + r["smoothness"] for r in rows]
    if objective[-1] > objective[0] + TIE * at_result["train_loss"]:
        lines.append(f"  the smoothness at its final weight prefers the result ({objective[0]:.4f} against "
                     f"{objective[-1]:.4f} in all)")
    return "\n".join(lines)


def chart(rows: list[dict], path: Path) -> None:
    plt = common.pyplot()
    figure, (loss_axis, error_axis) = plt.subplots(1, 2, figsize=(11, 4.2))
    for name in dict.fromkeys(r["case"] for r in rows):
        line = [r for r in rows if r["case"] == name and r["t"] != "truth"]
        t = [r["t"] for r in line]
        loss_axis.plot(t, [r["train_loss"] / line[0]["train_loss"] for r in line], marker=".", label=name)
        error_axis.plot(t, [r["deviatoric_error"] for r in line], marker=".", label=name)
    loss_axis.set(xlabel="t: result (0) to the truth's best grid (1)", ylabel="training loss / loss at the result",
                  title="data loss on the line")
    error_axis.set(xlabel="t", ylabel="relative deviatoric error", title="error on the line")
    loss_axis.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="+", type=Path, help="reconstruction output directories (grids)")
    parser.add_argument("--views", type=int, default=24, help="training (and held-out) views sampled per loss")
    parser.add_argument("--pixel-samples", type=int, default=16, help="stratified rays averaged per pixel")
    parser.add_argument("--output", type=Path, default=HERE / "experiments" / "results" / "loss_landscape")
    args = parser.parse_args()
    rows = []
    print(f"CPU: {cpu_name()}", flush=True)
    for directory in args.results:
        case_rows, text = landscape(directory, args.views, args.pixel_samples)
        rows += case_rows
        print(text, f"  ({case_rows[0]['views']} views, {case_rows[0]['seconds']} s)", sep="\n", flush=True)
        common.write_table(rows, args.output.with_suffix(".csv"))
        chart(rows, args.output.with_suffix(".png"))


if __name__ == "__main__":
    main()
