"""Resident memory of a reconstruction against its iterations: bounded, or growing?

Runs ``mi_nest.optimize`` on a target dataset (32 x 32 rotations at 64 x 64,
simulated if ``--data`` does not hold it yet) on the final grid from the first
iteration (no coarse-to-fine stages, whose grids differ in size) and reads the
process's resident memory (``VmRSS``) every ``--every`` iterations. It prints
the samples and a least-squares slope over the second half of the run, in MiB
per 1000 iterations: memory that grows with the iterations (a leak in the loop,
the history, the AD graph) shows there, while allocator warm-up stays in the
first half. ``--rotations`` shrinks the dataset for a quick check.

    python benchmarks/memory.py --data /tmp/t22/disk --iterations 6000
    python benchmarks/memory.py --scene kitten -D fringe_value=4500 --data /tmp/t22/kitten
"""
from __future__ import annotations

import argparse
import tempfile
import warnings
from pathlib import Path

import numpy as np

import mi_nest
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.reconstruct import FAST_OPTIONS, loop

from reconstruction import cpu_name


def resident_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS in /proc/self/status (Linux only)")


def sampled_run(scene, data, iterations, every, options):
    """``[(iteration, MiB)]`` after every ``every`` iterations of ``optimize``."""
    samples = []
    own = loop.Run.step

    def step(self, tracer):
        value = own(self, tracer)
        if (self.iteration + 1) % every == 0:
            samples.append((self.iteration + 1, resident_mib()))
        return value
    loop.Run.step = step
    try:
        mi_nest.optimize(scene, data, iterations=iterations, progress=False, coarse_to_fine=False,
                         track_error_every=0, **options)
    finally:
        loop.Run.step = own
    return samples


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="disk_compression")
    parser.add_argument("-D", dest="defines", action="append", default=["load=100", "contact_width=4"],
                        metavar="NAME=VALUE", help="scene defines (default: the disk target's)")
    parser.add_argument("--data", type=Path, help="dataset directory (simulated there if missing)")
    parser.add_argument("--rotations", type=int, default=32,
                        help="azimuths and elevations of the dataset simulated (default: 32, the target's)")
    parser.add_argument("--iterations", type=int, default=6000)
    parser.add_argument("--every", type=int, default=250)
    args = parser.parse_args()
    if args.scene != "disk_compression" and args.defines[:2] == ["load=100", "contact_width=4"]:
        args.defines = args.defines[2:]
    defines = dict(d.split("=", 1) for d in args.defines)
    warnings.simplefilter("ignore")
    # The fast schedule's batch (1024 pixels) at the finest stage's 4 rays per pixel, its learning rates.
    options = {name: FAST_OPTIONS[name] for name in ("batch_size", "final_learning_rate")}
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or Path(tmp) / "data"
        if not (data / "dataset.json").is_file():
            simulate(args.scene, data, SimulationSettings(azimuths=args.rotations, elevations=args.rotations, res=64),
                     defines=defines, progress=False)
        scene = mi_nest.load_scene(args.scene, res=64, **defines)
        print(f"{cpu_name()}; {args.scene} {defines}, {args.rotations} x {args.rotations} rotations at 64 x 64, the "
              f"final grid throughout, {args.iterations} iterations, options {options}")
        samples = sampled_run(scene, data, args.iterations, args.every, options)
    for iteration, mib in samples:
        print(f"  iteration {iteration:6d}: {mib:7.1f} MiB")
    later = np.array([s for s in samples if s[0] > args.iterations // 2])
    slope = np.polyfit(later[:, 0] / 1000, later[:, 1], 1)[0] if len(later) > 1 else float("nan")
    print(f"second half: {later[:, 1].min():.1f} to {later[:, 1].max():.1f} MiB, slope {slope:+.2f} MiB per 1000 "
          "iterations")


if __name__ == "__main__":
    main()
