"""Real specimens refract: what the straight-ray model loses, and how much the refraction-aware one recovers.

Each case simulates the scene with its part at n = 1.55 in air or in a bath
(``ext_ior``: the liquid around it, the tank's walls facing the camera in every
view), then reconstructs the same dataset twice with the defaults of
``mi_nest.optimize``, capped at ``--iterations``:

- **straight**: the scene loaded index-matched (``ior = ext_ior = 1``), as every
  other stress-tomography code assumes;
- **refraction-aware**: the scene with the dataset's own indices (geometry and
  indices known and fixed, only the stress trained).

It also times renders of each scene with and without refraction. Writes
``refraction.csv``, ``refraction_render.csv`` and ``refraction.png``. The
defaults are the demo's loop (the disk at 60 N over 4 mm contacts, 12 x 12
rotations at 48 x 48, a 32-node grid, 4,000 iterations: 10.6% index-matched),
so that each of the 20 reconstructions takes one or two minutes::

    .venv/bin/python experiments/refraction.py

``--preset targets`` runs the reconstruction targets' configuration instead
(``experiments/targets.py``: 32 x 32 rotations at 64 x 64, the disk at 100 N on
a 64-node grid, the kitten on a 32-node grid, each scene's options there),
capped at 20,000 iterations rather than minutes so that a busy machine changes
the time, not the result::

    .venv/bin/python experiments/refraction.py --preset targets --surroundings air

``--max-bounces N`` simulates the ghosts too (partial reflections, up to N per
path) and adds a third model, refraction-aware with the same ghosts; the
second then follows the transmitted path alone::

    .venv/bin/python experiments/refraction.py --max-bounces 4 --surroundings air

Each row also holds ``truth_loss``: the true field's held-out loss under that
model, what the model could reach at best on these images; ``--floors``
computes only those, from the datasets already simulated.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import common
import mi_nest
import targets
from mi_nest.reconstruct import REGULARISED
from mi_nest.reconstruct.evaluation import dataset_loss
from mi_nest.scene import specimen_shapes

PART = 1.55
SURROUNDINGS = {"air": 1.0, "water (1.33)": 1.33, "bath 1.45": 1.45, "bath 1.50": 1.50, "matched 1.55": 1.55}
SCENES = {"disk_compression": {"load": 60.0, "contact_width": 4.0}, "kitten": {"fringe_value": 4500.0}}
# Per preset: rotations, image resolution, iterations, each scene's (defines, reconstruction options).
PRESETS = {
    "demo": (12, 48, 4000, {name: (defines, {"resolution": 32, "regulariser": REGULARISED})
                            for name, defines in SCENES.items()}),
    "targets": (32, 64, 20_000, {name: targets.SCENES[name] for name in SCENES}),
}


def render_cost(name, defines, res, repeats=5):
    """Median seconds of a render at ``res`` with the part index-matched and refracting in air."""
    row = {"scene": name, "res": res}
    for label, indices in (("straight_s", {}), ("refracting_s", {"ior": PART})):
        scene = mi_nest.load_scene(name, res=res, spp=4, **defines, **indices)
        mi_nest.render(scene, progress=False)            # compiles the kernels
        seconds = []
        for _ in range(repeats):
            start = time.perf_counter()
            mi_nest.render(scene, progress=False)
            seconds.append(time.perf_counter() - start)
        row[label] = round(float(np.median(seconds)), 4)
    row["ratio"] = round(row["refracting_s"] / row["straight_s"], 2)
    print(row, flush=True)
    return row


def truth_loss(name, data, res, model_defines):
    """The held-out views' mean L1 error of the true field under a model: how well that model can explain the
    data at all (pixel centres against images averaged over each pixel)."""
    scene = mi_nest.load_scene(name, res=res, **model_defines)
    truth = specimen_shapes(scene)[0].interior_medium().field
    return round(dataset_loss(scene, mi_nest.Dataset(data), truth, scene.integrator().tracer, split="test"), 4)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=sorted(SCENES))
    parser.add_argument("--surroundings", nargs="+", default=list(SURROUNDINGS), choices=list(SURROUNDINGS))
    parser.add_argument("--preset", default="demo", choices=sorted(PRESETS),
                        help="demo: 12 x 12 at 48 x 48, 4,000 iterations; targets: experiments/targets.py's runs")
    parser.add_argument("--minutes", type=float, default=60.0, help="cap on each reconstruction")
    parser.add_argument("--max-bounces", type=int, default=0,
                        help="partial reflections per ghost path in the simulated data (0: the transmitted path alone)")
    parser.add_argument("--skip-timing", action="store_true", help="leave out the render timings")
    parser.add_argument("--floors", action="store_true",
                        help="only the true field's held-out loss under each model (refraction_floors.csv)")
    parser.add_argument("--output", type=Path, help="default: experiments/out/refraction[_PRESET][_ghostsN]")
    args = parser.parse_args()
    rotations, res, iterations, configurations = PRESETS[args.preset]
    output = args.output or Path("experiments/out/refraction" + ("" if args.preset == "demo" else f"_{args.preset}")
                                 + (f"_ghosts{args.max_bounces}" if args.max_bounces else ""))

    if not (args.skip_timing or args.floors):
        timing = [render_cost(name, configurations[name][0], 256) for name in args.scenes]
        common.write_table(timing, output / "refraction_render.csv")
    rows = []
    for name in args.scenes:
        scene_defines, options = configurations[name]
        for surrounding in args.surroundings:
            indices = {"ior": PART, "ext_ior": SURROUNDINGS[surrounding]}
            defines = {**scene_defines, **indices, "max_bounces": args.max_bounces}
            if args.floors:     # the datasets as simulated, whichever code simulated them
                data, simulated = common.dataset_directory(name, output, rotations, res, defines), 0.0
            else:
                data, simulated = common.dataset(name, output, rotations, res, defines)
            models = [("straight", {**scene_defines, "ior": 1.0, "ext_ior": 1.0}),
                      ("refraction-aware", {**defines, "max_bounces": 0})]
            if args.max_bounces:
                models.append(("refraction-aware with ghosts", defines))
            for model, model_defines in models:
                floor = truth_loss(name, data, res, model_defines)
                if args.floors:
                    rows.append({"scene": name, "surrounding": surrounding, "model": model, "truth_loss": floor})
                    print(rows[-1], flush=True)
                    continue
                label = f"{name} {surrounding} {model}"
                row, _ = common.reconstruct(name, data, output, label.replace(" ", "_"), args.minutes, res,
                                            model_defines, iterations=iterations, track_error_every=500, **options)
                rows.append({"scene": name, "surrounding": surrounding, "n_ratio": round(PART / indices["ext_ior"], 4),
                             "model": model, "simulate_s": round(simulated, 1),
                             "iterations_per_s": round(row["iterations"] / row["optimise_s"], 1), "truth_loss": floor,
                             **row})
            common.write_table(rows, output / ("refraction_floors.csv" if args.floors else "refraction.csv"))
    if args.floors:
        return
    plot(rows, output / "refraction.png", f"{rotations}x{rotations} rotations at {res}x{res}, {iterations} iterations")


def plot(rows, path, subtitle):
    """Per scene, the final error of each model against the liquid around the part."""
    plt = common.pyplot()
    scenes = list(dict.fromkeys(row["scene"] for row in rows))
    figure, axes = plt.subplots(1, len(scenes), figsize=(5.5 * len(scenes), 4), squeeze=False)
    for axis, name in zip(axes[0], scenes):
        surroundings = list(dict.fromkeys(row["surrounding"] for row in rows if row["scene"] == name))
        x = np.arange(len(surroundings))
        models = list(dict.fromkeys(row["model"] for row in rows))
        width = 0.8 / len(models)
        for index, model in enumerate(models):
            errors = [100 * float(next(r["deviatoric_error"] for r in rows if r["scene"] == name
                                       and r["surrounding"] == s and r["model"] == model)) for s in surroundings]
            bars = axis.bar(x + (index - (len(models) - 1) / 2) * width, errors, width=width, label=model)
            axis.bar_label(bars, fmt="%.0f", fontsize=7)
        axis.set_xticks(x, surroundings, fontsize=8)
        axis.set(ylabel="relative deviatoric stress error (%)", title=f"{name}, part n = {PART}")
        axis.legend(fontsize=8)
    figure.suptitle(f"straight rays against refraction-aware ({subtitle})", fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
