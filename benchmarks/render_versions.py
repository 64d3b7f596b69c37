"""Do this checkout's renders equal another's? The check that a speed-up kept the results.

Each version renders, in its own process from a copy of its tree laid out as its wheel installs it, the
shipped scenes at a small resolution and a gridded disk (a 33 x 29 x 24 stress grid, written once by this
checkout) through an oblique orthographic camera, which takes the projected-grid lookup, and a perspective
one, which does not. The script prints, per scene, the largest difference over the channels that the Jones
matrix determines (the angles ``char.theta`` and ``char.gamma`` are left out: they turn freely where the
retardance vanishes), relative to the channel's largest value or 1 if that is smaller (a Jones component
near zero everywhere has no scale of its own), and fails if one exceeds ``--tolerance``. Float32 rounding
in a product of hundreds of steps reaches a few 1e-5 when the operations are ordered differently.

    git worktree add /tmp/before 04d869c
    python benchmarks/render_versions.py --baseline /tmp/before
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from reconstruction import cpu_name, installed_layout, run

HERE = Path(__file__).resolve().parents[1]
SHIPPED = {"disk_compression": 64, "kitten": 64, "twisted_block": 64, "beam_bending": 64, "bracket": 48}

WORKER = r"""
import json, sys, warnings
import mitsuba as mi
import numpy as np
import mi_nest
args = json.loads(sys.argv[1])
output, grid, shipped = args["output"], args["grid"], args["shipped"]
warnings.simplefilter("ignore")
channels = {}
for name, res in shipped.items():
    channels.update({f"{name}/{c}": v for c, v in mi_nest.render(mi_nest.load_scene(name, res=res)).channels.items()})
T = mi.ScalarTransform4f
camera = T().look_at(origin=[40, -30, 60], target=[0, 0, 0], up=[0.3, 1, 0])
for projection, to_world in (("orthographic", camera @ T().scale([12, 12, 1])), ("perspective", camera)):
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "photoelastic", "step_size": 0.1},
        "light": {"type": "polariscope_light", "polarizer": 90.0, "qwp": 45.0},
        "sensor": {"type": "polariscope", "projection": projection, "analyzer": 0.0, "qwp": -45.0,
                   "to_world": to_world, "sampler": {"type": "independent", "sample_count": 4},
                   "film": {"type": "hdrfilm", "width": 64, "height": 64, "pixel_format": "luminance",
                            "rfilter": {"type": "box"}}},
        "specimen": {"type": "cube", "to_world": T().scale([10, 10, 3]),
                     "interior": {"type": "stress", "stress_optic_coefficient": 50.0, "filename": grid}}})
    channels.update({f"grid {projection}/{c}": v for c, v in mi_nest.render(scene).channels.items()})
np.savez(output, **channels)
print(json.dumps({"mi_nest": mi_nest.__file__}))
"""


def write_disk_grid(path: Path) -> None:
    import mi_nest  # noqa: F401  (sets the variant the fields need)
    from mi_nest.fields import DiskCompressionField
    from mi_nest.io.grid import StressGrid, save_stress_grid
    disk = DiskCompressionField(diameter=24.0, thickness=6.0, load=150.0, contact_width=4.0)
    low, high, nodes = (-10.0, -10.0, -3.0), (10.0, 10.0, 3.0), (33, 29, 24)
    axes = [np.linspace(a, b, n) for a, b, n in zip(low, high, nodes)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    stress = np.stack(disk.eval((x, y, z)), axis=-1).astype(np.float32)
    save_stress_grid(path, StressGrid(stress, np.array(low), np.array(high)))


def render(path_entry: Path, output: Path, grid: Path) -> dict[str, np.ndarray]:
    run(path_entry, {"output": str(output), "grid": str(grid), "shipped": SHIPPED}, WORKER)
    with np.load(output) as data:
        return dict(data)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", type=Path, required=True, help="another mi_nest checkout (a git worktree)")
    parser.add_argument("--tolerance", type=float, default=1e-4,
                        help="largest difference allowed, relative to the channel's largest value (or 1)")
    args = parser.parse_args()
    if not (args.baseline / "mi_nest").is_dir():
        parser.error(f"{args.baseline} is not an mi_nest checkout (no mi_nest/ in it)")
    print(f"{cpu_name()}; renders of this checkout against {args.baseline}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_disk_grid(tmp / "disk.npz")
        images = {name: render(installed_layout(tree, tmp / name), tmp / f"{name}.npz", tmp / "disk.npz")
                  for name, tree in (("this", HERE), ("baseline", args.baseline.resolve()))}
    worst = {}
    for key, baseline in images["baseline"].items():
        scene, channel = key.split("/", 1)
        if channel in ("char.theta", "char.gamma"):
            continue
        relative = float(np.max(np.abs(images["this"][key] - baseline))) / max(float(np.max(np.abs(baseline))), 1.0)
        if relative >= worst.get(scene, (-1.0, ""))[0]:
            worst[scene] = (relative, channel)
    for scene, (relative, channel) in worst.items():
        print(f"  {scene:22s} largest difference {relative:.1e} ({channel})")
    failed = [scene for scene, (relative, _) in worst.items() if relative > args.tolerance]
    if failed:
        raise SystemExit(f"differ by more than {args.tolerance:g}: {', '.join(failed)}")
    print(f"every scene within {args.tolerance:g} of the baseline")


if __name__ == "__main__":
    main()
