"""Where a reconstruction's stress error sits, and what its grid could reach at best.

For one saved reconstruction (``mi_nest.optimize(..., output=DIR)``) of a
simulated scene: the error's share in the most stressed points, the grid's
floors (the truth sampled at the nodes, and the least-squares best fit, at the
reconstruction's resolution and finer), the dataset's fringe aliasing, and a
figure of truth, reconstruction and error on the specimen's mid-plane. Run it as

    .venv/bin/python experiments/error_anatomy.py experiments/out/targets/results/disk_compression \\
        --scene disk_compression -D load=300 -D contact_width=4 --dataset experiments/out/targets/data/...
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import common
import numpy as np

import mi_nest
from mi_nest import occupancy
from mi_nest.physics.tensors import COMPONENTS
from mi_nest.reconstruct import FieldConfig, make_field, metrics
from mi_nest.reconstruct.checkpoints import load_field
from mi_nest.physics.tensors import deviatoric_part, tensor_norm
from mi_nest.scene import specimen_bounds, specimen_shapes

# Shares of the most stressed evaluation points whose part of the squared error is reported.
TOP_SHARES = (0.01, 0.05, 0.2)


def error_shares(estimate, reference):
    """``{share: (share of truth norm^2, share of error^2, relative error there)}`` over the most stressed points."""
    error = tensor_norm(estimate - reference) ** 2
    magnitude = tensor_norm(reference) ** 2
    order = np.argsort(-magnitude)
    shares = {}
    for share in TOP_SHARES:
        top = order[:max(1, int(share * len(order)))]
        shares[share] = (magnitude[top].sum() / magnitude.sum(), error[top].sum() / error.sum(),
                         np.sqrt(error[top].sum() / magnitude[top].sum()))
    return shares


def floors(field, truth, scene, shapes, points, resolutions):
    """``[(resolution, sampled floor, best-fit floor)]`` for grids like ``field`` at ``resolutions``."""
    rows = []
    for resolution in resolutions:
        grid = make_field(FieldConfig(kind="grid", resolution=resolution), field.bbox_min, field.bbox_max,
                          field.stress_scale)
        rows.append((resolution, metrics.representation_floor(grid, truth, points),
                     metrics.best_fit_floor(grid, truth, scene, shapes, points)))
        print(f"grid {resolution}: truth sampled {100 * rows[-1][1]:.1f}%, best fit {100 * rows[-1][2]:.1f}%",
              flush=True)
    return rows


def mid_plane(field, shapes, scene, samples=96):
    """Points on the plane through the specimen's centre normal to its thinnest side, and their inside mask."""
    low, high = specimen_bounds(shapes)
    normal = int(np.argmin(high - low))
    axes = [a for a in range(3) if a != normal]
    u, v = (np.linspace(low[a], high[a], samples) for a in axes)
    grid_u, grid_v = np.meshgrid(u, v)
    points = np.empty((grid_u.size, 3))
    points[:, axes[0]], points[:, axes[1]] = grid_u.ravel(), grid_v.ravel()
    points[:, normal] = 0.5 * (low[normal] + high[normal])
    inside = occupancy.inside(scene, shapes, points)
    return points, inside, [("xyz"[a]) for a in axes], (u[0], u[-1], v[0], v[-1])


def plot_slices(truth, estimate_field, scene, shapes, path, title):
    points, inside, labels, extent = mid_plane(estimate_field, shapes, scene)
    true = deviatoric_part(metrics.sample(truth, points))
    estimate = deviatoric_part(metrics.sample(estimate_field, points))
    side = int(np.sqrt(len(points)))
    plt = common.pyplot()
    figure, axes = plt.subplots(3, 6, figsize=(16, 8), squeeze=False)

    def show(axis, values, limit, cmap="RdBu_r"):
        image = np.where(inside, values, np.nan).reshape(side, side)
        axis.imshow(image, origin="lower", extent=extent, vmin=-limit if cmap == "RdBu_r" else 0, vmax=limit,
                    cmap=cmap)
        axis.set(xlabel=f"{labels[0]} (mm)", ylabel=f"{labels[1]} (mm)")
    scale = np.percentile(np.abs(true[inside]), 99) or 1.0
    for k, name in enumerate(COMPONENTS):
        show(axes[0, k], true[:, k], scale)
        axes[0, k].set_title(f"truth {name}", fontsize=9)
        show(axes[1, k], estimate[:, k], scale)
        axes[1, k].set_title(f"reconstruction {name}", fontsize=9)
    error = tensor_norm(estimate - true)
    magnitude = tensor_norm(true)
    show(axes[2, 0], magnitude, np.percentile(magnitude[inside], 99), "magma")
    axes[2, 0].set_title("|truth| (MPa)", fontsize=9)
    show(axes[2, 1], error, np.percentile(magnitude[inside], 99), "magma")
    axes[2, 1].set_title("|error| (MPa), same scale", fontsize=9)
    for axis in axes[2, 2:]:
        axis.axis("off")
    figure.suptitle(title + f" (mid-plane; colour limits: 99th percentile of the truth, {scale:.3g} MPa)")
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    print(f"wrote {path}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("result", type=Path, help="a reconstruction's output directory (field.npz)")
    parser.add_argument("--scene", required=True)
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--dataset", type=Path, help="the dataset it was fitted to (for its fringe aliasing)")
    parser.add_argument("--finer", type=int, nargs="*", default=[], help="further grid resolutions to floor")
    parser.add_argument("--output", type=Path, help="where the CSV and PNG go (default: the result directory)")
    args = parser.parse_args()
    defines = {k: float(v) for k, v in (d.split("=", 1) for d in args.defines)}
    output = args.output or args.result
    name = args.result.name

    scene = mi_nest.load_scene(args.scene, res=64, **defines)
    shapes = specimen_shapes(scene)
    truth = shapes[0].interior_medium().field
    field = load_field(args.result / "field.npz")
    points = metrics.evaluation_points(scene, shapes)
    probe = metrics.ErrorProbe(truth, points)
    estimate = deviatoric_part(metrics.sample(field, points))
    total = probe.error_of(estimate)
    print(f"{name}: {field}: deviatoric error {100 * total:.1f}% over {len(points)} points")
    row = {"result": str(args.result), "scene": args.scene, "defines": defines, "field": field.describe(),
           "deviatoric_error": round(total, 4)}
    for share, (truth_share, error_share, relative) in error_shares(estimate, probe.reference).items():
        print(f"  the {100 * share:g}% most stressed points: {100 * truth_share:.1f}% of the truth's norm^2, "
              f"{100 * error_share:.1f}% of the squared error, {100 * relative:.1f}% relative error there")
        row[f"top{100 * share:g}%_error_share"] = round(error_share, 4)
        row[f"top{100 * share:g}%_relative_error"] = round(relative, 4)
    rest = np.argsort(-tensor_norm(probe.reference))[int(TOP_SHARES[1] * len(points)):]
    row["relative_error_outside_top5%"] = round(float(np.linalg.norm(tensor_norm(estimate[rest] - probe.reference[rest]))
                                                      / np.linalg.norm(tensor_norm(probe.reference[rest]))), 4)
    print(f"  elsewhere: {100 * row['relative_error_outside_top5%']:.1f}% relative error")
    if field.kind == "grid":
        for resolution, sampled, best in floors(field, truth, scene, shapes, points,
                                                [field.config.resolution, *args.finer]):
            row[f"grid{resolution}_sampled_floor"] = round(sampled, 4)
            row[f"grid{resolution}_best_fit_floor"] = round(best, 4)
    if args.dataset is not None:
        aliasing = json.loads((args.dataset / "dataset.json").read_text()).get("fringe_aliasing")
        print(f"  dataset fringe aliasing: {aliasing}")
        if aliasing:
            row.update({f"aliasing_{k}": v for k, v in aliasing.items()})
    common.write_table([row], output / f"anatomy_{name}.csv")
    plot_slices(truth, field, scene, shapes, output / f"anatomy_{name}.png",
                f"{name}: {100 * total:.1f}% deviatoric error")


if __name__ == "__main__":
    main()
