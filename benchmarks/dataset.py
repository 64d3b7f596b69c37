"""Dataset simulation cost: the paper's 32 x 32 rotations at 256 x 256, this checkout against another.

Times ``mi_nest.dataset.simulate`` on the disk and the kitten (read noise 0.01)
and prints the wall time, the render time and the time for noise, masks and
writing the EXR per rotation, and the peak resident memory of the run. Each
version runs in its own process from a copy of its tree laid out as a wheel
installs it; with ``--baseline`` the versions alternate, so a busy machine slows
both alike, and the script prints their ratio. ``--rotations`` shrinks the grid
for a quick estimate (the per-rotation costs do not depend on it).

    python benchmarks/dataset.py                         # 32 x 32, both scenes, this checkout
    git worktree add /tmp/before HEAD~3 && python benchmarks/dataset.py --baseline /tmp/before
"""
import argparse
import tempfile
from pathlib import Path

from reconstruction import cpu_name, installed_layout, run

HERE = Path(__file__).resolve().parents[1]
SCENES = {"disk": "disk_compression", "kitten": "kitten"}

WORKER = r"""
import json, resource, sys, tempfile, time, warnings
import mi_nest
from mi_nest.dataset import CameraModel, SimulationSettings, simulate
args = json.loads(sys.argv[1])
settings = SimulationSettings(azimuths=args["rotations"], elevations=args["rotations"], res=args["res"],
                              spp=args["spp"], camera=CameraModel(read_noise=0.01))
with tempfile.TemporaryDirectory() as directory, warnings.catch_warnings():
    warnings.simplefilter("ignore")       # oblique views of dense fields alias; not timed here
    start = time.perf_counter()
    report = simulate(args["scene"], directory, settings, progress=False)
    total = time.perf_counter() - start
print(json.dumps({"total": total, "render": report.render_seconds, "write": report.write_seconds,
                  "count": report.rendered, "rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "mi_nest": mi_nest.__file__}))
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="another mi_nest checkout to compare with (e.g. a git worktree)")
    parser.add_argument("--rotations", type=int, default=32, help="per axis (default: 32, the paper's)")
    parser.add_argument("--res", type=int, default=256)
    parser.add_argument("--spp", type=int, default=1)
    parser.add_argument("--scenes", default="disk,kitten")
    args = parser.parse_args()
    print(f"{cpu_name()}; {args.rotations} x {args.rotations} rotations over 180 x 180 deg, {args.res}x{args.res}, "
          f"spp {args.spp}, read noise 0.01")
    print(f"{'scene':8s} {'version':14s} {'total s':>8s} {'render ms':>10s} {'write ms':>9s} {'peak MiB':>9s}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        versions = {"this checkout": installed_layout(HERE, tmp / "current")}
        if args.baseline:
            versions["baseline"] = installed_layout(args.baseline.resolve(), tmp / "baseline")
        for round_, name in enumerate(args.scenes.split(",")):
            totals = {}
            # The first of a pair may pay for kernels the second finds cached: alternate who goes first.
            for version, path_entry in list(versions.items())[::1 if round_ % 2 == 0 else -1]:
                result = run(path_entry, {"scene": SCENES[name], "rotations": args.rotations, "res": args.res,
                                          "spp": args.spp}, WORKER)
                count = result["count"]
                totals[version] = result["total"]
                print(f"{name:8s} {version:14s} {result['total']:8.1f} {result['render'] / count * 1e3:10.1f} "
                      f"{result['write'] / count * 1e3:9.1f} {result['rss_mib']:9.0f}", flush=True)
            if args.baseline:
                ratio = totals["baseline"] / totals["this checkout"]
                print(f"{name:8s} wall time, baseline / this checkout: {ratio:.2f}x")


if __name__ == "__main__":
    main()
