"""The replay's two walks side by side: through the segments the primal walk kept, and querying the scene again.

Runs ``mi_nest.optimize`` on the final grid (no coarse-to-fine stages) up to
``--at`` iterations, takes that run's field and tracer, draws one batch as the
loop draws it (2,048 pixels x the dataset's rays per pixel, up to 4) and times,
best of ``--repeats`` interleaved, the primal march and the replay of both
kinds at the grid's step and at one step per segment (the walk alone). It also
prints how far the two replays' gradients are apart. Simulates a small
dataset (``--rotations``: 8 x 8 at 64 px, 4 samples per pixel) unless ``--data`` is given.

    python benchmarks/replay.py --scene stacked_disks -D load=300 -D contact_width=4
    python benchmarks/replay.py --scene disk_compression -D load=100 -D contact_width=4 --resolution 64
"""
from __future__ import annotations

import argparse
import tempfile
import warnings
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

import mi_nest
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.reconstruct import loop
from mi_nest.reconstruct.forward import forward_step
from mi_nest.reconstruct.rays import stratified

from iteration_profile import optimize_stepping_with
from reconstruction import cpu_name
from spectral import best_of


class Captured(Exception):
    pass


def captured_run(scene, data, resolution, at):
    """The optimisation's run object and tracer at iteration ``at``."""
    held = {}
    own = loop.Run.step

    def step(self, tracer):
        if self.iteration == at:
            held["run"], held["tracer"] = self, tracer
            raise Captured
        return own(self, tracer)
    try:
        optimize_stepping_with(scene, data, at + 1, step, {"resolution": resolution, "coarse_to_fine": False})
    except Captured:
        pass
    return held["run"], held["tracer"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="stacked_disks")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--data", type=Path, help="dataset directory (default: a small one simulated here)")
    parser.add_argument("--resolution", type=int, default=64, help="grid nodes along the longest axis")
    parser.add_argument("--at", type=int, default=30, help="iterations before the batch is drawn")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--rotations", type=int, default=8, help="azimuths and elevations simulated (default: 8)")
    args = parser.parse_args()
    defines = dict(d.split("=", 1) for d in args.defines)
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or Path(tmp) / "data"
        if not (data / "dataset.json").is_file():
            settings = SimulationSettings(azimuths=args.rotations, elevations=args.rotations, res=64, spp=4)
            simulate(args.scene, data, settings, defines=defines, progress=False)
        scene = mi_nest.load_scene(args.scene, res=64, **defines)
        run, tracer = captured_run(scene, data, args.resolution, args.at)
        rng = np.random.default_rng(0)
        samples = run.pixel_samples()
        positions, rows, columns, _ = run.dataset.ray_batch(2048, rng, views_per_batch=16)
        rays, right = run.view_rays.rays(*(np.repeat(a, samples) for a in (positions, rows, columns)),
                                         jitter=stratified(len(rows), samples, rng))
        dr.eval(rays, right)
        parameters = [run.optimizer[name] for name in run.optimizer.keys()]
        grid_step = forward_step(run.config, run.field)
        print(f"{cpu_name()}; {args.scene} {defines}, grid {'x'.join(map(str, run.field.shape))}, "
              f"{dr.width(rays.o)} rays, {dr.thread_count()} Dr.Jit threads, best of {args.repeats}")
        for name, step in (("the grid's step", grid_step), ("one step a segment", 1e3 * grid_step)):
            traced, times, gradients = {}, {}, {}
            for kept in (False, True):
                def primal(kept=kept):
                    traced[kept] = tracer.trace_rays(run.scene, rays, right, seed=5, field=run.field,
                                                     step_size=step, view=run.channels.view, replayable=kept)
                times[("primal", kept)] = 1000 * best_of(args.repeats, primal)[0]
                adjoint = tuple(mi.Float(np.random.default_rng(1).normal(size=dr.width(rays.o)).astype(np.float32))
                                for _ in traced[kept].state)

                def replay(kept=kept):
                    for parameter in parameters:
                        dr.clear_grad(parameter)
                    tracer.backpropagate_rays(run.scene, rays, right, traced[kept], adjoint, seed=5, field=run.field,
                                              step_size=step, view=run.channels.view)
                    dr.eval([dr.grad(parameter) for parameter in parameters])
                times[("replay", kept)] = 1000 * best_of(args.repeats, replay)[0]
                gradients[kept] = np.concatenate([dr.grad(p).numpy().ravel() for p in parameters])
            apart = np.abs(gradients[True] - gradients[False]).max() / max(np.abs(gradients[False]).max(), 1e-30)
            print(f"  {name}: primal {times[('primal', False)]:.2f} ms (keeping its segments "
                  f"{times[('primal', True)]:.2f}); replay querying the scene {times[('replay', False)]:.2f} ms, "
                  f"through the kept segments {times[('replay', True)]:.2f} ms: "
                  f"{times[('replay', False)] / times[('replay', True)]:.2f}x; gradients apart by {apart:.1e} "
                  f"of their largest")


if __name__ == "__main__":
    main()
