"""One GPU against this machine's CPU cores (issue 38): the same work on each Mitsuba variant, side by side.

For each variant this machine can run (``llvm_ad_mono`` always, ``cuda_ad_mono`` where a CUDA device is), in a
process of its own:

- **forward**: a render of the disk at 300 N (``res`` x ``res``, ``spp`` samples per pixel, steps of ``step``
  mm), the median of ``repeats`` after a warm-up; ray-steps per second from the rays' paths;
- **reconstruction**: ``iterations`` iterations of ``mi-nest reconstruct``'s defaults on a disk dataset of
  8 x 8 rotations at 64 px (simulated once on the CPU); iterations per second;
- **a paper-size dataset**: ``rotations`` rotations of the paper's 512 x 512 (at ``spp`` 4, as the shipped
  scene), timed and scaled to its 32 x 32 rotations.

Prints a table with the device named and the GPU-to-CPU ratios. Without a CUDA device it says so and prints the
CPU's row: the CPU path does not wait for a GPU.

    python benchmarks/gpu.py                            # the full set (a few minutes on 2 CPU cores)
    python benchmarks/gpu.py --res 64 --iterations 20 --rotations 1   # a quick look
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from reconstruction import cpu_name

HERE = Path(__file__).resolve().parents[1]

WORKER = r"""
import json, statistics, sys, tempfile, time, warnings
args = json.loads(sys.argv[1])
from mi_nest import variants
variants.use(args["variant"])
import drjit as dr, mitsuba as mi, numpy as np
import mi_nest
from mi_nest.dataset import SimulationSettings, simulate
warnings.simplefilter("ignore")          # dense fringes alias; not what is timed
scene = mi_nest.load_scene("disk_compression", res=args["res"], spp=args["spp"], step=args["step"], load=300,
                           contact_width=4)
mi_nest.render(scene)                    # the kernels compiled, not timed
times = []
for _ in range(args["repeats"]):
    start = time.perf_counter()
    result = mi_nest.render(scene)
    times.append(time.perf_counter() - start)
length = np.asarray(result.channels["path.length"])
ray_steps = float(np.ceil(length / args["step"]).sum()) * args["spp"]
forward = ray_steps / statistics.median(times)
from mi_nest.reconstruct import optimize
truth = mi_nest.load_scene("disk_compression", res=64, load=60, contact_width=4)
start = time.perf_counter()
optimize(truth, args["data"], iterations=args["iterations"], progress=False)
iterations = args["iterations"] / (time.perf_counter() - start)
settings = SimulationSettings(azimuths=args["rotations"], elevations=1, res=512)
with tempfile.TemporaryDirectory() as directory:
    start = time.perf_counter()
    simulate("disk_compression", directory, settings, defines={"load": 300, "contact_width": 4}, progress=False)
    per_rotation = (time.perf_counter() - start) / args["rotations"]
print(json.dumps({"variant": mi.variant(), "forward": forward, "iterations": iterations,
                  "paper_dataset_min": per_rotation * 1024 / 60}))
"""


def measure(variant: str, settings: dict) -> dict:
    done = subprocess.run([sys.executable, "-c", WORKER, json.dumps({**settings, "variant": variant})], cwd=HERE,
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{variant}: {done.stderr.strip().splitlines()[-1]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def gpu_name() -> str | None:
    try:
        done = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                              text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip().splitlines()[0] if done.returncode == 0 and done.stdout.strip() else None


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--res", type=int, default=512, help="forward render's width and height (default: 512)")
    parser.add_argument("--spp", type=int, default=4, help="samples per pixel (default: 4)")
    parser.add_argument("--step", type=float, default=0.25, help="step in mm (default: 0.25)")
    parser.add_argument("--repeats", type=int, default=5, help="timed renders (default: 5)")
    parser.add_argument("--iterations", type=int, default=300, help="reconstruction iterations (default: 300)")
    parser.add_argument("--rotations", type=int, default=4, help="paper-size rotations timed (default: 4)")
    args = parser.parse_args()
    import drjit as dr
    cuda = bool(dr.has_backend(dr.JitBackend.CUDA))
    found = gpu_name() if cuda else None
    print(f"CPU: {cpu_name()}, {os.cpu_count()} cores; GPU: {found or ('a CUDA device' if cuda else 'none')}",
          flush=True)
    with tempfile.TemporaryDirectory() as scratch:
        data = Path(scratch) / "disk"
        done = subprocess.run([sys.executable, "-m", "mi_nest.cli", "--variant", "llvm_ad_mono", "simulate",
                               "disk_compression", "-o", str(data), "--azimuth", "8", "--elevation", "8", "--res",
                               "64", "--noise", "0.01", "-D", "load=60", "-D", "contact_width=4"], cwd=HERE,
                              capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(done.stderr.strip().splitlines()[-1])
        settings = {"res": args.res, "spp": args.spp, "step": args.step, "repeats": args.repeats,
                    "iterations": args.iterations, "rotations": args.rotations, "data": str(data)}
        rows = [measure("llvm_ad_mono", settings)]
        if cuda:
            rows.append(measure("cuda_ad_mono", settings))
    print(f"\n| variant | forward ray-steps/s ({args.res}^2, {args.spp} spp) | reconstruction iterations/s | "
          "paper-size dataset (32 x 32 at 512 px) |")
    print("|---|---:|---:|---:|")
    for row in rows:
        print(f"| {row['variant']} | {row['forward']:.3g} | {row['iterations']:.1f} | "
              f"{row['paper_dataset_min']:.1f} min |")
    if len(rows) == 2:
        cpu, gpu = rows
        print(f"\nGPU / CPU: forward {gpu['forward'] / cpu['forward']:.1f}x, reconstruction "
              f"{gpu['iterations'] / cpu['iterations']:.1f}x, dataset "
              f"{cpu['paper_dataset_min'] / gpu['paper_dataset_min']:.1f}x")
    else:
        print("\nNo CUDA device on this machine: the CPU's row only (run this where there is a GPU for the ratios).")


if __name__ == "__main__":
    main()
