"""Several wavelengths in one march (``mi_nest/tracer/spectral.py``) against one march per wavelength.

For 1, 3, 8 and 16 wavelengths (the white LED's spread, 400 to 700 nm), times in one run on one machine:

- a render of a shipped scene through the ``photoelastic`` integrator with every wavelength a lane of one
  spectral march (what ``mi-nest render --white-light`` runs), against one monochromatic render per wavelength;
- a ray batch (``Tracer.trace_rays``, what a reconstruction from several bands marches), likewise;

each on the scene's own analytic field and on that field sampled on a 64^3 grid (a reconstruction's: a
trilinear lookup per step). Prints ray-steps/s per wavelength and the cost of ``n`` wavelengths against one
(the issue's target: three cost well under three times one), and checks that each lane equals the monochromatic
march at its wavelength. Last, a white-light render of the shipped disk at 300 N (41 wavelengths) against one
render per wavelength, index-matched and at n = 1.55 in air (refracted paths, ghosts included).

    python benchmarks/spectral.py [--scene twisted_block] [--step 0.1] [--res 256] [--repeats 3]
"""
from __future__ import annotations

import argparse
import time
import warnings

import drjit as dr
import mitsuba as mi
import numpy as np

import mi_nest
from mi_nest.fields.grid import GridField
from mi_nest.io.grid import StressGrid
from mi_nest.render import View, phase_scale
from reconstruction import cpu_name


def parse_args():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="twisted_block", help="a shipped scene (default: axes turning along "
                        "20 mm chords)")
    parser.add_argument("--res", type=int, default=256, help="film width and height (one ray per pixel)")
    parser.add_argument("--step", type=float, default=0.1, help="march step in mm")
    parser.add_argument("--method", default="product", choices=("product", "magnus4", "linear"))
    parser.add_argument("--lanes", type=int, nargs="+", default=[1, 3, 8, 16], help="wavelength counts")
    parser.add_argument("--grid-nodes", type=int, default=64, help="nodes per axis of the grid field")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs of each case (the best is kept)")
    args = parser.parse_args()
    if args.res < 1 or args.repeats < 1 or args.grid_nodes < 2 or min(args.lanes) < 1 or args.step <= 0:
        parser.error("--res, --repeats and --lanes must be at least 1, --grid-nodes at least 2, --step positive")
    return args


def sampled_grid(scene: mi.Scene, nodes: int) -> GridField:
    """The scene's own field sampled on ``nodes``^3 nodes over its specimens' box."""
    medium = mi_nest.scene.specimen_media(scene)[0]
    box = scene.shapes()[0].bbox()
    low, high = np.array(box.min), np.array(box.max)
    axes = [np.linspace(lo, hi, nodes) for lo, hi in zip(low, high)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    points = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    stress = mi_nest.fields.base.sample(medium.field, points).reshape(nodes, nodes, nodes, 6)
    return GridField(StressGrid(stress.astype(np.float32), low, high))


def best_of(repeats, run):
    run()       # compiles
    dr.sync_thread()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = run()
        dr.sync_thread()        # Dr.Jit's LLVM kernels run asynchronously
        times.append(time.perf_counter() - start)
    return min(times), out


def camera_rays(scene: mi.Scene, res: int) -> tuple[mi.Ray3f, mi.Vector3f]:
    """One ray per pixel of the scene's camera, and each ray's image-right direction."""
    sensor = scene.sensors()[0]
    index = dr.arange(mi.UInt32, res * res)
    position = (mi.Point2f(mi.Float(index % res), mi.Float(index // res)) + 0.5) / res
    rays, _ = sensor.sample_ray(0.0, 0.5, position, mi.Point2f(0.5))
    right = sensor.world_transform() @ mi.Vector3f(-1, 0, 0)
    return rays, dr.zeros(mi.Vector3f, res * res) + right


def white_light(args, ior: float):
    """``render_white_light`` of the shipped disk at 300 N (the white LED's 41 wavelengths) of index ``ior`` in air
    (1: index-matched, straight rays; otherwise the refracted walk, ghosts included) against one render per
    wavelength, both through ``in_white_light``."""
    from mi_nest.render import WavelengthRenders, in_white_light, render_white_light, white_light as led
    disk = mi_nest.load_scene("disk_compression", res=args.res, spp=1, load=300, ior=ior)
    light = led()

    def one_at_a_time(wavelengths):
        result = mi_nest.render(disk, view=View(phase_scale=phase_scale(disk, 1.0, wavelengths[0])))
        return [{"Y": result.main}], result
    spectral_seconds, spectral = best_of(args.repeats, lambda: render_white_light(disk, light))
    each_seconds, each = best_of(args.repeats, lambda: in_white_light(WavelengthRenders(one_at_a_time), light))
    difference = max(float(np.abs(spectral.channels[c] - each.channels[c]).max()) for c in ("R", "G", "B"))
    print(f"white light, disk_compression at 300 N, n = {ior:g}, {args.res}x{args.res}, {len(light.wavelengths)} "
          f"wavelengths: {spectral_seconds:.3f} s in spectral marches, {each_seconds:.3f} s one render per "
          f"wavelength ({each_seconds / spectral_seconds:.2f}x); sRGB differs by {difference:.1e}")


def main():
    args = parse_args()
    warnings.simplefilter("ignore")     # the shipped loads alias at some resolutions; the timing is the point
    scene = mi_nest.load_scene(args.scene, res=args.res, spp=1, step=args.step)
    integrator = scene.integrator()
    integrator.configure(method=args.method, step_size=args.step)
    tracer = integrator.tracer
    fields = {"analytic": None, "grid": sampled_grid(scene, args.grid_nodes)}
    rays, right = camera_rays(scene, args.res)
    print(f"{cpu_name()}; {args.scene} {args.res}x{args.res}, {args.method}, step {args.step} mm, "
          f"best of {args.repeats}")
    print(f"{'field':9s} {'path':7s} {'waves':>5s} {'one march s':>11s} {'each alone s':>12s} "
          f"{'ray-steps/s/wave':>16s} {'cost vs 1':>9s} {'speed-up':>8s} {'lane error':>10s}")
    costs = {}
    for field_name, field in fields.items():
        for path in ("render", "rays"):
            single = None
            for count in args.lanes:
                wavelengths = np.linspace(400.0, 700.0, count) if count > 1 else np.array([532.0])
                scales = [phase_scale(scene, 1.0, float(w)) for w in wavelengths]
                lanes = tuple((f"I.{w:g}", s) for w, s in zip(wavelengths, scales))
                if path == "render":
                    def spectral_run():
                        return mi_nest.render(scene, field=field, view=View(lanes=lanes)).channels

                    def alone(scale):
                        return mi_nest.render(scene, field=field, view=View(phase_scale=scale)).channels["Y"]
                    seconds, channels = best_of(args.repeats, spectral_run)
                    length = channels["path.length"]
                    lane_images = [channels[name] for name, _ in lanes]
                else:
                    def spectral_run():
                        return tracer.trace_rays(scene, rays, right, field=field, view=View(lanes=lanes))

                    def alone(scale):
                        return tracer.trace_rays(scene, rays, right, field=field, view=View(phase_scale=scale))
                    seconds, traced = best_of(args.repeats, spectral_run)
                    length = traced.length.numpy()
                    lane_images = [np.array(q).T for q in traced.jones()]
                alone_seconds = 0.0
                error = 0.0
                for scale, lane in zip(scales, lane_images):
                    taken, image = best_of(args.repeats, lambda: alone(scale))
                    if path == "rays":      # the traced state, read after the timing
                        image = np.array(image.jones()).T
                    alone_seconds += taken
                    error = max(error, float(np.abs(image - lane).max()))
                if count == 1:
                    single = alone_seconds
                ray_steps = float(np.ceil(np.asarray(length) / args.step).sum())
                per_wave = ray_steps * count / seconds
                cost = seconds / single if single else float("nan")
                costs[(field_name, path, count)] = cost
                print(f"{field_name:9s} {path:7s} {count:5d} {seconds:11.4f} {alone_seconds:12.4f} "
                      f"{per_wave:16.3e} {cost:9.2f} {alone_seconds / seconds:7.2f}x {error:10.1e}", flush=True)
    for ior in (1.0, 1.55):
        white_light(args, ior)
    if 3 in args.lanes and 1 in args.lanes:
        for field_name in fields:
            print(f"{field_name}: 3 wavelengths in one march cost {costs[(field_name, 'render', 3)]:.2f} (render) "
                  f"and {costs[(field_name, 'rays', 3)]:.2f} (ray batch) times one wavelength's (target: well "
                  "under 3)")


if __name__ == "__main__":
    main()
