"""What refraction costs: renders and reconstruction iterations, straight against refracting, side by side.

For the disk and the kitten, three models of the same part, measured in one
run on one machine (rounds alternate between them, so a busy machine slows all
alike):

- **straight**: index-matched (no interface: the straight walk's kernel);
- **refracting**: n = 1.55 in air, the transmitted path alone (``max_bounces 0``);
- **with ghosts**: the same with partial reflections (``max_bounces``, default
  the integrator's).

Renders at 256 x 256, 4 samples per pixel, 0.1 mm steps (median of the rounds): seconds and
ray-steps per second of the transmitted walk (its marched length over the step,
``path.length``; the ghost walk's steps are not counted, only its time).
Reconstruction: iterations per second of ``mi_nest.optimize`` on a small
dataset simulated with each model (12 x 12 rotations at 48 x 48, 2048 rays a
batch; ``--rotations`` fewer for a quick check), after a first run that compiles
the kernels.

    python benchmarks/refraction.py
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

import mi_nest
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.tracer.refraction import DEFAULT_MAX_BOUNCES

from reconstruction import cpu_name

SCENES = {"disk_compression": {"load": 60.0, "contact_width": 4.0}, "kitten": {"fringe_value": 4500.0}}


def models(bounces):
    return {"straight": {"ior": 1.0, "max_bounces": 0}, "refracting": {"ior": 1.55, "max_bounces": 0},
            f"with ghosts ({bounces})": {"ior": 1.55, "max_bounces": bounces}}


def render_round(scene, spp):
    """Seconds of one render of a loaded scene, and the ray-steps its transmitted walk marched."""
    start = time.perf_counter()
    result = mi_nest.render(scene, progress=False)
    seconds = time.perf_counter() - start
    steps = float(np.asarray(result.channels["path.length"], dtype=np.float64).sum()) * spp
    return seconds, steps / scene.integrator().tracer.config.step_size


def reconstruction_rate(name, defines, data, iterations):
    scene = mi_nest.load_scene(name, res=48, **defines)
    result = mi_nest.optimize(scene, data, iterations=iterations, kind="grid", resolution=32, batch_size=2048,
                              seed=0, progress=False)
    return len(result.history) / result.seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--res", type=int, default=256)
    parser.add_argument("--spp", type=int, default=4)
    parser.add_argument("--step", type=float, default=0.1,
                        help="march step (mm): fine enough that the march, not the render's fixed costs, is timed")
    parser.add_argument("--iterations", type=int, default=300)
    parser.add_argument("--rotations", type=int, default=12, help="of the reconstruction's datasets, per axis")
    parser.add_argument("--max-bounces", type=int, default=DEFAULT_MAX_BOUNCES)
    parser.add_argument("--skip-reconstruction", action="store_true")
    args = parser.parse_args()
    warnings.simplefilter("ignore", RuntimeWarning)
    print(f"CPU: {cpu_name()}")
    variants = models(args.max_bounces)
    for name, scene_defines in SCENES.items():
        scenes = {label: mi_nest.load_scene(name, res=args.res, spp=args.spp, step=args.step, **scene_defines,
                                            **defines) for label, defines in variants.items()}
        for scene in scenes.values():
            render_round(scene, args.spp)            # compiles
        times = {label: [] for label in variants}
        steps = {}
        for _ in range(args.rounds):
            for label, scene in scenes.items():
                seconds, steps[label] = render_round(scene, args.spp)
                times[label].append(seconds)
        straight = statistics.median(times["straight"])
        print(f"\n{name}: render {args.res}x{args.res}, {args.spp} spp, step {args.step} mm, median of {args.rounds}")
        for label in variants:
            median = statistics.median(times[label])
            print(f"  {label:18s} {median:7.3f} s  {steps[label] / median:9.3g} ray-steps/s  "
                  f"{median / straight:5.2f}x the straight render")
        if args.skip_reconstruction:
            continue
        rates = {}
        with tempfile.TemporaryDirectory() as tmp:
            for label, defines in variants.items():
                data = Path(tmp) / label.split()[0]
                settings = SimulationSettings(azimuths=args.rotations, elevations=args.rotations, res=48, spp=1)
                simulate(name, data, settings, defines={**scene_defines, **defines}, progress=False)
                reconstruction_rate(name, {**scene_defines, **defines}, data, 20)        # compiles
                rates[label] = reconstruction_rate(name, {**scene_defines, **defines}, data, args.iterations)
        print(f"{name}: reconstruction, {args.iterations} iterations of 2048 rays")
        for label, rate in rates.items():
            print(f"  {label:18s} {rate:7.1f} it/s  {rate / rates['straight']:5.2f}x the straight rate")


if __name__ == "__main__":
    main()
