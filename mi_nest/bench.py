"""Speed against accuracy of the integration methods (``mi-nest bench accuracy``).

Each case is a shipped scene rendered with every method over a sweep of step
sizes, against a converged reference (``magnus4`` at an eighth of the finest
step). Per pixel the error is the largest absolute error of the 16 normalised
intensities; the chart shows its 99th percentile over the image, because the
few pixels next to a point load (an infinite stress, where even float32
evaluation of the field loses the phase) would otherwise decide the maximum,
which the CSV keeps too. The cost is the best of two render times, also given
per megaray-step.
"""
from __future__ import annotations

import csv
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from .render import NonFiniteImageError, render
from .scene import load_scene
from .tracer.methods import POINTS
from .tracer.registry import FIXED, METHODS
from .physics import MEASUREMENTS

# (label, method, points) of every curve: each method that marches as named, at each point of those that take one.
CURVES = tuple(curve for name in FIXED for curve in
               ([(f"{name}, {point}", name, point) for point in POINTS] if METHODS[name].takes_points
                else [(name, name, None)]))


@dataclass(frozen=True)
class Case:
    label: str
    scene: str
    steps: tuple                 # step sizes (mm), coarse to fine
    defines: dict = field(default_factory=dict)


CASES = {
    "disk": Case("disk along its axis (steps commute)", "disk_compression", (6.0, 3.0, 1.5, 0.75, 0.375)),
    "twisted": Case("twisted block (axes turn along rays)", "twisted_block", (10.0, 5.0, 2.5, 1.25, 0.625, 0.3125)),
    "stacked": Case("two stacked disks at 45 degrees", "stacked_disks", (6.0, 3.0, 1.5, 0.75, 0.375, 0.1875)),
    "kitten": Case("kitten (3D-TSV FEM field)", "kitten", (8.0, 4.0, 2.0, 1.0, 0.5),
                   {"grid_resolution": 48}),
    "dense": Case("disk, dense fringes (5 kN)", "disk_compression", (6.0, 3.0, 1.5, 0.75, 0.375),
                  {"load": 5000}),
}


def _render(case, method, points, step, res):
    """``(channels, best seconds of two renders)``; channels None where the method blew up (NaN or inf pixels:
    rk4 at long steps), which the chart marks."""
    scene = load_scene(case.scene, res=res, spp=1, step=step, **case.defines)
    integrator = scene.integrator()
    integrator.configure(method=method, points=points or "midpoint")
    best, result = float("inf"), None
    with warnings.catch_warnings():
        # rk4 warns when it is not unitary; here that is the measurement itself.
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            render(scene)                          # compiles the kernel
            for _ in range(2):
                start = time.perf_counter()
                result = render(scene)
                best = min(best, time.perf_counter() - start)
        except NonFiniteImageError:
            start = time.perf_counter()         # the time of the render that blew up, for the chart's cross
            try:
                render(scene)
            except NonFiniteImageError:
                pass
            return None, time.perf_counter() - start
    return result.channels, best


# One row of the accuracy CSV: the case and method names, then the numbers.
Row = dict[str, str | float]


def run_accuracy(case_names: Sequence[str] = tuple(CASES), res: int = 256, progress: bool = True) -> list[Row]:
    """Rows of ``case, method, step_mm, error (99th pct), error_max, seconds, megaray_steps, ...``."""
    rows = []
    bar = None
    total = sum(len(CASES[n].steps) for n in case_names) * len(CURVES)
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=total, desc="bench accuracy", unit="render")
    for name in case_names:
        case = CASES[name]
        reference, _ = _render(case, "magnus4", None, min(case.steps) / 8, res)
        for label, method, points in CURVES:
            for step in case.steps:
                channels, seconds = _render(case, method, points, step, res)
                if channels is None:
                    error = error_max = float("inf")
                else:
                    per_pixel = np.max([np.abs(channels[n] - reference[n]) for n in MEASUREMENTS], axis=0)
                    error, error_max = float(np.percentile(per_pixel, 99)), float(np.max(per_pixel))
                # Rays times their steps (the march takes ceil(L / step) per chord; L / step here).
                megaray_steps = float(np.sum(np.ceil(reference["path.length"] / step))) / 1e6
                rows.append({"case": name, "method": label, "step_mm": step, "error": error, "error_max": error_max,
                             "seconds": seconds, "megaray_steps": megaray_steps,
                             "seconds_per_megaray_step": seconds / max(megaray_steps, 1e-12)})
                if bar is not None:
                    bar.update()
    if bar is not None:
        bar.close()
    return rows


# Errors are drawn within [floor, ceiling]; crosses at the ceiling mark a method that blew up.
ERROR_FLOOR, ERROR_CEILING = 1e-7, 10.0


def _blew_up(error):
    return not np.isfinite(error) or error > ERROR_CEILING


def _shown(error):
    return ERROR_CEILING if _blew_up(error) else max(error, ERROR_FLOOR)


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the (seconds, error) points no other point beats in both."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], float("inf")
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def write_results(rows: Sequence[Row], folder: str | Path) -> tuple[Path, Path]:
    """``accuracy.csv`` and ``accuracy.png`` (error against time, a panel per case) in ``folder``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "accuracy.csv", "w", newline="") as out:
        writer = csv.DictWriter(out, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    cases = list(dict.fromkeys(r["case"] for r in rows))
    figure, axes = plt.subplots(1, len(cases), figsize=(4.2 * len(cases), 4.0), squeeze=False)
    for axis, name in zip(axes[0], cases):
        case_rows = [r for r in rows if r["case"] == name]
        for label, *_ in CURVES:
            curve = [r for r in case_rows if r["method"] == label]
            shown = [_shown(r["error"]) for r in curve]
            line, = axis.loglog([r["seconds"] for r in curve], shown, "o-", label=label, markersize=3)
            blown = [(r["seconds"], e) for r, e in zip(curve, shown) if _blew_up(r["error"])]
            if blown:
                axis.plot(*zip(*blown), "x", color=line.get_color(), markersize=8)
        front = pareto_front([(r["seconds"], _shown(r["error"])) for r in case_rows])
        axis.loglog([case_rows[i]["seconds"] for i in front], [_shown(case_rows[i]["error"]) for i in front],
                    "k--", linewidth=1, label="Pareto front")
        axis.set_ylim(ERROR_FLOOR / 2, ERROR_CEILING * 2)
        axis.set_title(CASES[name].label, fontsize=9)
        axis.set_xlabel("render time (s)")
        axis.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("error of the 16 intensities, 99th pct (x: blew up)")
    axes[0][0].legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(folder / "accuracy.png", dpi=110)
    plt.close(figure)
    return folder / "accuracy.csv", folder / "accuracy.png"
