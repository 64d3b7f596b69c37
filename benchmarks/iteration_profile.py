"""Where a reconstruction iteration's time goes: its phases, and kernels against the rest.

Simulates the target dataset if it is not there yet (32 x 32 rotations at 64 x
64), runs ``mi_nest.optimize`` with its defaults for ``--iterations`` and, over
the iterations from ``--first`` on (by default the last fifth, in the finest
coarse-to-fine stage), times each phase of the step between ``dr.sync_thread()``
calls, then (a second run) sums the kernels' execution and compile times from
Dr.Jit's kernel history. The timers add syncs: the phases' sum exceeds an
untimed step a little. ``--rotations`` shrinks the dataset for a quick check.

    python benchmarks/iteration_profile.py --scene disk_compression -D load=100 -D contact_width=4
    python benchmarks/iteration_profile.py --scene kitten -D fringe_value=4500
"""
from __future__ import annotations

import argparse
import collections
import tempfile
import time
import warnings
from pathlib import Path

import drjit as dr

import mi_nest
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.dataset.loader import Dataset
from mi_nest.reconstruct import loop
from mi_nest.reconstruct.config import option_value
from mi_nest.reconstruct.rays import ViewRays

from reconstruction import cpu_name


def timed(totals, name, function, active):
    def wrapper(*args, **kwargs):
        if not active():
            return function(*args, **kwargs)
        dr.sync_thread()
        start = time.perf_counter()
        result = function(*args, **kwargs)
        dr.sync_thread()
        totals[name] += time.perf_counter() - start
        return result
    return wrapper


def optimize_stepping_with(scene, data, iterations, step, options):
    """``mi_nest.optimize``'s defaults (but ``options``) with ``step`` in place of the loop's own for the run."""
    own = loop.Run.step
    loop.Run.step = step
    try:
        mi_nest.optimize(scene, data, iterations=iterations, progress=False, **options)
    finally:
        loop.Run.step = own


def phases(scene, data, iterations, first, options):
    totals = collections.defaultdict(float)
    count = [0]
    active = lambda: count[0] >= first      # noqa: E731
    saved = (Dataset.ray_batch, ViewRays.rays, loop.l1_loss, loop.Run._check_divergence)
    Dataset.ray_batch = timed(totals, "ray_batch (NumPy)", Dataset.ray_batch, active)
    ViewRays.rays = timed(totals, "camera rays", ViewRays.rays, active)
    loop.l1_loss = timed(totals, "loss", loop.l1_loss, active)
    loop.Run._check_divergence = timed(totals, "divergence check", loop.Run._check_divergence, active)
    step = loop.Run.step
    wrapped = {}

    def counted_step(self, tracer):
        kind = type(tracer)
        if kind not in wrapped:
            wrapped[kind] = (kind.trace_rays, kind.backpropagate_rays)
            kind.trace_rays = timed(totals, "trace_rays (primal)", kind.trace_rays, active)
            kind.backpropagate_rays = timed(totals, "backpropagate_rays (replay)", kind.backpropagate_rays, active)
        result = timed(totals, "whole step", step, active)(self, tracer)
        count[0] += 1
        return result
    try:
        optimize_stepping_with(scene, data, iterations, counted_step, options)
    finally:
        Dataset.ray_batch, ViewRays.rays, loop.l1_loss, loop.Run._check_divergence = saved
        for kind, (trace, replay) in wrapped.items():
            kind.trace_rays, kind.backpropagate_rays = trace, replay
    return {name: seconds / (iterations - first) for name, seconds in totals.items()}


def kernels(scene, data, iterations, first, options):
    totals = {"wall": 0.0, "execution": 0.0, "compile": 0.0, "launches": 0}
    by_kernel = collections.defaultdict(float)
    count = [0]
    step = loop.Run.step
    timed_step = timed(totals, "wall", step, lambda: True)

    def recorded_step(self, tracer):
        if count[0] < first:
            count[0] += 1
            return step(self, tracer)
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        result = timed_step(self, tracer)
        history = dr.kernel_history()
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        totals["execution"] += sum(k.get("execution_time", 0) for k in history) / 1000
        totals["compile"] += sum(k.get("codegen_time", 0) + k.get("backend_time", 0) for k in history) / 1000
        totals["launches"] += len(history)
        for kernel in history:
            name = f"{kernel.get('operation_count', 0)} ops, {kernel.get('size', 0)} lanes"
            by_kernel[name] += kernel.get("execution_time", 0) / 1000
        count[0] += 1
        return result
    optimize_stepping_with(scene, data, iterations, recorded_step, options)
    totals["kernels"] = {name: seconds / (iterations - first) for name, seconds in by_kernel.items()}
    return {name: value / (iterations - first) if name != "kernels" else value for name, value in totals.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="disk_compression")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--iterations", type=int, default=500)
    parser.add_argument("--first", type=int, help="first iteration measured (default: the last fifth)")
    parser.add_argument("--data", type=Path, help="dataset directory (default: a temporary one)")
    parser.add_argument("--rotations", type=int, default=32,
                        help="azimuths and elevations of the dataset simulated (default: 32, the target's)")
    parser.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                        help="an option of mi_nest.optimize instead of its default (repeatable)")
    args = parser.parse_args()
    defines = dict(d.split("=", 1) for d in args.defines)
    options = {name: option_value(name, text) for name, text in (o.split("=", 1) for o in args.option)}
    first = args.first if args.first is not None else args.iterations * 4 // 5
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or Path(tmp) / "data"
        if not (data / "dataset.json").is_file():      # a given dataset is used as it is (another version's too)
            simulate(args.scene, data, SimulationSettings(azimuths=args.rotations, elevations=args.rotations, res=64),
                     defines=defines, progress=False)
        scene = mi_nest.load_scene(args.scene, res=64, **defines)
        print(f"{cpu_name()}; {args.scene} {defines}, {args.rotations} x {args.rotations} rotations at 64 x 64, "
              f"optimize's defaults, iterations {first} to {args.iterations}, options {options or 'none'}")
        measured = phases(scene, data, args.iterations, first, options)
        for name, seconds in sorted(measured.items(), key=lambda kv: -kv[1]):
            print(f"  {name:32s} {1000 * seconds:7.2f} ms/iteration")
        totals = kernels(scene, data, args.iterations, first, options)
        print("  largest kernels (IR operations, lanes):")
        for name, seconds in sorted(totals["kernels"].items(), key=lambda kv: -kv[1])[:6]:
            print(f"    {name:30s} {1000 * seconds:7.2f} ms/iteration")
        print(f"  kernels execute {1000 * totals['execution']:.1f} ms of {1000 * totals['wall']:.1f} "
              f"({totals['launches']:.0f} launches), compile {1000 * totals['compile']:.2f} ms, the rest (Python, "
              f"tracing, launching, NumPy) {1000 * (totals['wall'] - totals['execution'] - totals['compile']):.1f} ms")


if __name__ == "__main__":
    main()
