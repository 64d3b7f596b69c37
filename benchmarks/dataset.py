"""Dataset simulation cost (issue 5): the paper's 32 x 32 rotations at 256 x 256.

Times ``mi_nest.dataset.simulate`` on the disk and the kitten and prints, per
rotation, the render time next to the time for noise, masks and writing the EXR,
measured side by side in the same run. ``--rotations`` shrinks the grid for a
quick estimate (the per-rotation costs do not depend on it).

    python benchmarks/dataset.py                         # 32 x 32, both scenes
    python benchmarks/dataset.py --rotations 8 --scenes disk
"""
import argparse
import tempfile
import time
import warnings

from mi_nest.dataset import CameraModel, SimulationSettings, simulate

SCENES = {"disk": "disk_compression", "kitten": "kitten"}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rotations", type=int, default=32, help="per axis (default: 32, the paper's)")
    parser.add_argument("--res", type=int, default=256)
    parser.add_argument("--spp", type=int, default=1)
    parser.add_argument("--scenes", default="disk,kitten")
    args = parser.parse_args()
    settings = SimulationSettings(azimuths=args.rotations, elevations=args.rotations, res=args.res, spp=args.spp,
                                  camera=CameraModel(read_noise=0.01))
    print(f"{args.rotations} x {args.rotations} rotations over 180 x 180 deg, {args.res}x{args.res}, spp {args.spp}, "
          "read noise 0.01")
    print(f"{'scene':8s} {'total s':>8s} {'render ms':>10s} {'write ms':>9s} {'write/render':>13s}")
    for name in args.scenes.split(","):
        with tempfile.TemporaryDirectory() as directory, warnings.catch_warnings():
            warnings.simplefilter("ignore")       # oblique views of dense fields alias; not timed here
            start = time.perf_counter()
            report = simulate(SCENES[name], directory, settings, progress=False)
            total = time.perf_counter() - start
        count = report.rendered
        print(f"{name:8s} {total:8.1f} {report.render_seconds / count * 1e3:10.1f} "
              f"{report.write_seconds / count * 1e3:9.1f} {report.write_seconds / report.render_seconds:12.1f}x")


if __name__ == "__main__":
    main()
