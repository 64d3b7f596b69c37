"""Along the load, from the zero field to the truth and past it: the intensities' loss and the neighbour loss.

    python experiments/neighbour_landscape.py DATASET [DATASET...] [--pixels 8192] [--output DIR]

Each DATASET is a simulated dataset (the accuracy suite's, say); its recorded scene gives the true field, whose
phases are scaled by ``s`` from 0 to 1.5. At every ``s`` a fixed batch of training pixels is traced and scored as a
reconstruction scores it: the L1 loss of the 16 intensities (``reconstruct/losses.py``, one ray per pixel centre)
and the neighbour loss (``reconstruct/neighbours.py``: each pixel and a neighbour, weighted by the pixels'
polarisation). A descent from zero meets every local minimum of the line before the truth at ``s = 1``: the
script counts them. Writes ``neighbour_landscape.csv`` and ``.png`` under ``--output``.
"""
from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

import mi_nest
from mi_nest.dataset.truth import recorded_scene
from mi_nest.reconstruct.channels import ChannelModel
from mi_nest.reconstruct.losses import l1_loss
from mi_nest.reconstruct.neighbours import NeighbourTargets
from mi_nest.reconstruct.rays import ViewRays
from mi_nest.scene import scene_tracer
from mi_nest.tracer import View

SCALES = np.round(np.linspace(0.0, 1.5, 61), 4)


def landscape(directory: Path, pixels: int, seed: int = 0) -> list[dict]:
    dataset = mi_nest.Dataset(directory)
    scene = recorded_scene(dataset.index["source"]).load(res=dataset.resolution[0])
    rng = np.random.default_rng(seed)
    positions, rows, columns, targets = dataset.ray_batch(pixels, rng)
    pairs = NeighbourTargets(dataset).pairs(positions, rows, columns, rng)
    view_rays, tracer, channels = ViewRays(scene, dataset), scene_tracer(scene), ChannelModel.of(dataset, scene)
    own = view_rays.rays(positions, rows, columns)
    both = view_rays.rays(*pairs.pixels)
    rows_out = []
    for scale in SCALES:
        view = View(phase_scale=max(float(scale), 1e-6))     # 0 is refused as no phase at all
        intensity = l1_loss(tracer.trace_rays(scene, *own, view=view).jones(), targets, 1, None, channels)
        neighbour = pairs.loss(tracer.trace_rays(scene, *both, view=view).jones(), 0)
        rows_out.append({"dataset": directory.name, "scale": float(scale), "intensity_loss": float(intensity[0]),
                         "neighbour_loss": float(neighbour[0])})
    return rows_out


def minima_before_truth(values: np.ndarray) -> int:
    """Local minima of ``values`` (along SCALES) strictly between 0 and the truth's scale 1."""
    inner = np.flatnonzero((SCALES > 0) & (SCALES < 1))
    return int(sum(values[i] < values[i - 1] and values[i] < values[i + 1] for i in inner))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--pixels", type=int, default=8192)
    parser.add_argument("--output", type=Path, default=Path("experiments/results"))
    args = parser.parse_args()
    rows = [row for directory in args.datasets for row in landscape(directory, args.pixels)]
    args.output.mkdir(parents=True, exist_ok=True)
    with open(args.output / "neighbour_landscape.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = list(dict.fromkeys(row["dataset"] for row in rows))
    columns = min(len(names), 4)
    lines = -(-len(names) // columns)
    figure, axes = plt.subplots(lines, columns, figsize=(4.2 * columns, 3.4 * lines), squeeze=False)
    for axis in axes.flat[len(names):]:
        axis.set_visible(False)
    for axis, name in zip(axes.flat, names):
        mine = [row for row in rows if row["dataset"] == name]
        for key, label in (("intensity_loss", "intensities (L1)"), ("neighbour_loss", "neighbours")):
            values = np.array([row[key] for row in mine])
            axis.plot(SCALES, values / values[0], label=f"{label}: {minima_before_truth(values)} minima before 1")
            print(f"{name}: {label}: {minima_before_truth(values)} local minima between 0 and the truth; "
                  f"at the truth {values[np.argmin(np.abs(SCALES - 1))]:.4f}, at zero {values[0]:.4f}")
        axis.axvline(1.0, color="k", lw=0.6)
        axis.set(title=name, xlabel="the true field scaled by", ylabel="loss / loss of the zero field")
        axis.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(args.output / "neighbour_landscape.png", dpi=120)
    print(f"wrote {args.output / 'neighbour_landscape.csv'} and .png")


if __name__ == "__main__":
    main()
