"""Forward-rendering throughput: the Dr.Jit ``photoelastic`` integrator versus plain NumPy.

Both sides render the same rays through the same specimen with the same physics
functions (``mi_nest.physics``): a ``res x res`` orthographic view along -z of a
box of depth ``L`` whose every ray is split into exactly ``steps`` midpoint steps.
Each side produces the same outputs (Jones quaternion, characteristic parameters,
the scene's own intensity ``Y`` and the 16 multi-axis polariscope intensities),
so the work is comparable. The script checks that the two agree, times both and
prints ray-steps per second and their ratio.

The twisted field varies only along z, so all pixels of an image are equal; every
ray is still traced and marched on both sides, and the script checks that the
NumPy rays start where Mitsuba's do.

    python benchmarks/forward.py                      # analytic twisted field, 256^2, 256 steps
    python benchmarks/forward.py --field grid         # the same field sampled on a 64^3 grid
    python benchmarks/forward.py --cold-cache         # include LLVM compilation in the first run

See docs/performance.md for measured numbers and their analysis.
"""
from __future__ import annotations

import argparse
import atexit
import math
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# Target from the project plan: Dr.Jit at least this many times faster than NumPy
# at 256 x 256 rays and 256 steps per ray.
TARGET_RATIO = 20.0

# Specimen and optics: the shipped twisted_block scene (scenes/twisted_block.xml),
# a 30 x 30 mm cross-section whose stress axes turn by rate * depth = 180 degrees.
CROSS_SECTION = 30.0        # mm, box extent along x and y
VIEW_FRACTION = 0.8         # the view covers 80 % of the cross-section: every ray crosses the box
CAMERA_DISTANCE = 100.0     # mm from the box centre, on +z


def parse_args(argv=None):
    parser = argparse.ArgumentParser(
        description="Time the Dr.Jit photoelastic integrator against a vectorised NumPy "
                    "implementation of the same model on the same rays, and check they agree.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--res", type=int, default=256, help="film width and height in pixels (1 ray each)")
    parser.add_argument("--steps", type=int, default=256, help="march steps per ray")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs of each method")
    parser.add_argument("--stat", choices=("best", "median"), default="best",
                        help="which of the timed runs the throughput and ratio use")
    parser.add_argument("--field", choices=("analytic", "grid"), default="analytic",
                        help="'analytic': the closed-form twisted model; 'grid': the same field "
                             "sampled on a regular grid (.npz) and trilinearly interpolated")
    parser.add_argument("--grid-res", type=int, default=64, help="grid nodes per axis for --field grid")
    parser.add_argument("--grid-lookup", choices=("trilinear", "scipy"), default="trilinear",
                        help="NumPy side of --field grid: a hand-written float trilinear lookup, "
                             "or scipy.interpolate.RegularGridInterpolator (float64, slower)")
    parser.add_argument("--numpy-dtype", choices=("float32", "float64"), default="float32",
                        help="NumPy precision; float32 matches Dr.Jit's and is the fair comparison")
    parser.add_argument("--depth", type=float, default=20.0, help="box depth L along z in mm")
    parser.add_argument("--amplitude", type=float, default=0.3, help="twisted field amplitude in MPa")
    parser.add_argument("--rate", type=float, default=9.0, help="twist rate in degrees per mm")
    parser.add_argument("--stress-optic", type=float, default=50.0,
                        help="stress-optic coefficient C in Brewster")
    parser.add_argument("--drjit-threads", type=int, default=None,
                        help="Dr.Jit worker threads (unset: one per core)")
    parser.add_argument("--cold-cache", action="store_true",
                        help="use an empty temporary Dr.Jit kernel cache so the first run includes "
                             "LLVM compilation even if ~/.drjit already holds the kernel")
    args = parser.parse_args(argv)
    if args.res < 1 or args.steps < 1 or args.repeats < 1 or args.grid_res < 2:
        parser.error("--res, --steps and --repeats must be >= 1 and --grid-res >= 2")
    return args


# --------------------------------------------------------------------------- scene

def step_size_for(depth, steps):
    """A step length for which the integrator's ``ceil(chord / step)`` is exactly ``steps``.

    ``depth / steps`` itself is fragile: the chord is measured in float32 between two
    hit points, and a chord one ulp too long gives ``steps + 1``. With
    ``depth / (steps - 0.5)`` the quotient is ``steps - 0.5``, half a step from both
    neighbouring integers. The integrator then marches with ``h = chord / steps``.
    """
    step = depth / (steps - 0.5)
    chord = np.float32(depth)
    assert math.ceil(float(chord * (1 + 1e-6)) / float(np.float32(step))) == steps
    assert math.ceil(float(chord * (1 - 1e-6)) / float(np.float32(step))) == steps
    return step


def twisted_parameters(args):
    """The ``twisted`` model: axis z, origin on the face where the light enters (z = -L/2)."""
    return dict(amplitude=args.amplitude, rate=args.rate, angle=0.0,
                axis=(0.0, 0.0, 1.0), reference=(1.0, 0.0, 0.0),
                origin=(0.0, 0.0, -0.5 * args.depth))


def write_grid(args, directory):
    """Sample the twisted field on the box's nodes and save it as a stress-grid .npz."""
    from mi_nest.fields import TwistedField
    from mi_nest.io.grid import StressGrid, save_stress_grid

    half = np.array([0.5 * CROSS_SECTION, 0.5 * CROSS_SECTION, 0.5 * args.depth])
    n = args.grid_res
    axes = [np.linspace(-h, h, n) for h in half]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")   # (Z, Y, X) order
    stress = np.stack(TwistedField(**twisted_parameters(args)).eval((x, y, z)), axis=-1)
    grid = StressGrid(stress.astype(np.float32), -half, half)
    path = Path(directory) / "twisted_grid.npz"
    save_stress_grid(path, grid)
    return path, grid


def build_scene(args, grid_path=None):
    import mitsuba as mi

    T = mi.ScalarTransform4f
    half_view = 0.5 * VIEW_FRACTION * CROSS_SECTION
    medium = {"type": "stress", "stress_optic_coefficient": args.stress_optic}
    if grid_path is None:
        params = twisted_parameters(args)
        medium.update(model="twisted", amplitude=params["amplitude"], rate=params["rate"],
                      angle=params["angle"], axis=mi.ScalarVector3f(params["axis"]),
                      reference=mi.ScalarVector3f(params["reference"]),
                      origin=mi.ScalarPoint3f(params["origin"]))
    else:
        medium["filename"] = str(grid_path)
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "photoelastic", "step_size": step_size_for(args.depth, args.steps)},
        "light": {"type": "polariscope_light", "polarizer": 90.0},
        "sensor": {
            "type": "polariscope",
            "projection": "orthographic",
            "analyzer": 0.0,
            # Looking along -z with up +y: image right = +x, image up = +y, and the
            # light travels along +z. The scale sets the half-width of the view.
            "to_world": T().look_at(origin=[0, 0, CAMERA_DISTANCE], target=[0, 0, 0], up=[0, 1, 0])
                        @ T().scale([half_view, half_view, 1.0]),
            # One ray per pixel through its centre: identical rays for both methods.
            "sampler": {"type": "stratified", "sample_count": 1, "jitter": False},
            "film": {"type": "hdrfilm", "width": args.res, "height": args.res,
                     "pixel_format": "luminance", "rfilter": {"type": "box"}},
        },
        "specimen": {
            "type": "cube",   # [-1, 1]^3 scaled to CROSS_SECTION x CROSS_SECTION x depth
            "to_world": T().scale([0.5 * CROSS_SECTION, 0.5 * CROSS_SECTION, 0.5 * args.depth]),
            "interior": medium,
        },
    })


# --------------------------------------------------------------------------- NumPy reference

def camera_rays(res, depth, dtype):
    """Entry points on the camera-side face (z = +L/2) and the march direction -z.

    Pixel (row, col) looks through its centre; row 0 is the top of the image (+y).
    """
    half_view = 0.5 * VIEW_FRACTION * CROSS_SECTION
    centres = (np.arange(res) + 0.5) / res
    x = half_view * (2.0 * centres - 1.0)
    y = half_view * (1.0 - 2.0 * centres)
    ox, oy = np.meshgrid(x, y, indexing="xy")
    origin = tuple(a.ravel().astype(dtype) for a in (ox, oy, np.full_like(ox, 0.5 * depth)))
    direction = (0.0, 0.0, -1.0)
    return origin, direction


def trilinear_lookup(grid, dtype):
    """NumPy twin of ``GridField.eval``: nodal trilinear interpolation, clamped at the box.

    Written for speed so that the NumPy baseline is not a straw man: one flat
    table per stress component (1D ``take`` is the fastest NumPy gather) and
    separable lerps along x, then y, then z.
    """
    nz, ny, nx = grid.stress.shape[:3]
    tables = [np.ascontiguousarray(grid.stress[..., c].ravel(), dtype=dtype) for c in range(6)]
    shape = (nx, ny, nz)
    scale = [(n - 1) / float(hi - lo) for n, lo, hi in zip(shape, grid.bbox_min, grid.bbox_max)]
    row_offsets = {(dz, dy): (dz * ny + dy) * nx for dz in (0, 1) for dy in (0, 1)}

    def eval_grid(p):
        index, frac = [], []
        for axis in range(3):
            t = np.clip((p[axis] - float(grid.bbox_min[axis])) * scale[axis], 0, shape[axis] - 1)
            i0 = np.minimum(t.astype(np.int32), shape[axis] - 2)   # t >= 0: truncation is floor
            index.append(i0)
            frac.append((t - i0).astype(dtype))                    # int32 - float32 is float64
        ix, iy, iz = index
        fx, fy, fz = frac
        base = (iz * ny + iy) * nx + ix
        stress = []
        for table in tables:
            along_x = {}
            for key, offset in row_offsets.items():
                left = table.take(base + offset)
                right = table.take(base + offset + 1)
                along_x[key] = left + fx * (right - left)
            near = along_x[0, 0] + fy * (along_x[0, 1] - along_x[0, 0])
            far = along_x[1, 0] + fy * (along_x[1, 1] - along_x[1, 0])
            stress.append(near + fz * (far - near))
        return tuple(stress)

    return eval_grid


def scipy_lookup(grid, dtype):
    """The same lookup through scipy's RegularGridInterpolator (evaluates in float64)."""
    from scipy.interpolate import RegularGridInterpolator

    nodes = [np.linspace(grid.bbox_min[a], grid.bbox_max[a], n)
             for a, n in zip((2, 1, 0), grid.stress.shape[:3])]
    interpolator = RegularGridInterpolator(nodes, grid.stress.astype(np.float64), method="linear")
    lower, upper = grid.bbox_min[::-1], grid.bbox_max[::-1]

    def eval_grid(p):
        zyx = np.clip(np.stack([p[2], p[1], p[0]], axis=-1), lower, upper)
        return tuple(interpolator(zyx).astype(dtype).T)

    return eval_grid


def numpy_render(field_eval, phase_rate, res, depth, steps, dtype):
    """The integrator's forward model, vectorised over all rays, one Python loop over steps.

    Mirrors the integrator's ``product`` method (``mi_nest/tracer/methods.py``) and its
    outputs (``PhotoelasticIntegrator.outputs``): midpoint samples marching
    from the camera-side face away from the camera, each new step multiplied on the
    right, renormalised after every step.
    """
    from mi_nest.physics import MEASUREMENTS, projection, standard_polariscope, su2
    from mi_nest.physics.aliasing import fringe_aliasing

    origin, direction = camera_rays(res, depth, dtype)
    k = tuple(-x for x in direction)          # light travels towards the camera
    # Python floats: NumPy keeps float32 arrays float32 when mixed with them.
    u, v = (tuple(float(c) for c in w) for w in projection.transverse_basis(k, (1.0, 0.0, 0.0)))
    h = depth / steps
    q = su2.identity(origin[0])
    fringe = (0.0, 0.0)
    for i in range(steps):
        t = (i + 0.5) * h
        p = tuple(o + d * t for o, d in zip(origin, direction))
        tensor = tuple(phase_rate * s for s in field_eval(p))
        p_diff, q_diff = projection.project(tensor, u, v)
        generator = su2.generator(p_diff, q_diff, h)
        q = su2.renormalize(su2.multiply(q, su2.exponential(generator)))
        fringe = (fringe[0] + generator[1], fringe[1] + generator[2])

    radiance = 1.0
    channels = {"Y": radiance * standard_polariscope(polarizer=90.0, analyzer=0.0).intensity(q)}
    channels.update(zip(("jones.a", "jones.b", "jones.c", "jones.d"), q))
    channels.update(zip(("char.delta", "char.theta", "char.gamma"), su2.characteristic_parameters(q)))
    channels.update({name: radiance * scope.intensity(q) for name, scope in MEASUREMENTS.items()})
    channels["fringe.order"] = np.hypot(*fringe) / np.float32(np.pi)
    channels["path.length"] = np.full_like(q[0], depth)
    channels = {name: np.asarray(c).reshape(res, res) for name, c in channels.items()}
    fringe_aliasing(channels["fringe.order"], channels["path.length"] > 0)   # the integrator's guard
    return channels


def twisted_closed_form(args, phase_rate):
    """Jones quaternion of the twisted retarder (docs/physics.md section 5): an independent check."""
    from mi_nest.physics import su2
    from mi_nest.physics.polariscope import rotation

    G = 2.0 * phase_rate * args.amplitude * args.depth        # 2 pi C A L / lambda
    psi = math.radians(args.rate) * args.depth
    X = math.sqrt(psi ** 2 + (G / 2) ** 2)
    sinc = math.sin(X) / X
    M = np.array([[math.cos(X) - 0.5j * G * sinc, psi * sinc],
                  [-psi * sinc, math.cos(X) + 0.5j * G * sinc]])
    return su2.from_matrix(rotation(math.degrees(psi)) @ M)   # theta_0 = 0 at the entry face


# --------------------------------------------------------------------------- timing

def interleaved_timings(functions, repeats):
    """Best-effort fair wall-clock timing: ``repeats`` rounds, each calling every function once.

    Interleaving the methods exposes them to the same machine state; on a shared
    (virtualised) host the speed can change by 2x within seconds, and timing one
    method after the other would turn that into a bogus ratio. Every function must
    return materialised host arrays, so the clock covers the real work.
    """
    seconds = {name: [] for name in functions}
    results = {}
    for _ in range(repeats):
        for name, function in functions.items():
            start = time.perf_counter()
            results[name] = function()
            seconds[name].append(time.perf_counter() - start)
    return seconds, results


def drjit_kernels(dr):
    """The JIT kernels launched since the last call, from Dr.Jit's kernel history."""
    return [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]


def check_camera(scene, args):
    """The NumPy rays start where Mitsuba's camera rays hit the box (corner pixels)."""
    import mitsuba as mi

    sensor = scene.sensors()[0]
    origin, _ = camera_rays(args.res, args.depth, np.float64)
    corners = [(0, 0), (0, args.res - 1), (args.res - 1, 0), (args.res - 1, args.res - 1)]
    worst = 0.0
    for row, col in corners:
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((col + 0.5) / args.res, (row + 0.5) / args.res),
                                   mi.Point2f(0.5, 0.5))
        o, d = np.array(ray.o).ravel(), np.array(ray.d).ravel()
        hit = o + d * (o[2] - 0.5 * args.depth) / -d[2]
        index = row * args.res + col
        worst = max(worst, abs(hit[0] - origin[0][index]), abs(hit[1] - origin[1][index]))
    return worst


def main(argv=None):
    args = parse_args(argv)
    if args.cold_cache:
        # Must happen before Dr.Jit is imported: it reads the cache location at start-up.
        cache = tempfile.mkdtemp(prefix="drjit-cache-")
        atexit.register(shutil.rmtree, cache, ignore_errors=True)
        os.environ["DRJIT_CACHE_DIR"] = cache
    import mi_nest          # first: it points Dr.Jit at a working LLVM and sets the variant
    from mi_nest.scene import specimen_media
    import drjit as dr
    import mitsuba as mi

    if args.drjit_threads:
        dr.set_thread_count(args.drjit_threads)
    dtype = np.dtype(args.numpy_dtype)
    rays = args.res * args.res
    ray_steps = rays * args.steps

    with tempfile.TemporaryDirectory() as tmp:
        grid_path = grid = None
        if args.field == "grid":
            grid_path, grid = write_grid(args, tmp)
        scene = build_scene(args, grid_path)
        medium, = specimen_media(scene)
        phase_rate = medium.phase_rate

        # ---- Dr.Jit: the first run pays for tracing and compilation (or a kernel-cache
        # load); the kernel history says which, and how long LLVM took.
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        start = time.perf_counter()
        mi_nest.render(scene)
        first_seconds = time.perf_counter() - start
        first_kernels = drjit_kernels(dr)
        dr.set_flag(dr.JitFlag.KernelHistory, False)

        # ---- NumPy: the same model with the same physics functions.
        if grid is None:
            field_eval = medium.field.eval          # TwistedField.eval runs on NumPy arrays
        elif args.grid_lookup == "trilinear":
            field_eval = trilinear_lookup(grid, dtype)
        else:
            field_eval = scipy_lookup(grid, dtype)

        def drjit_core():
            # The integrator's own output: an (H, W, channels) tensor, copied to the host.
            image = mi.render(scene, spp=1)
            return image.numpy()

        def drjit_api():
            # The public entry point: the same render plus one contiguous array per channel.
            return mi_nest.render(scene).channels

        def numpy_reference():
            return numpy_render(field_eval, phase_rate, args.res, args.depth, args.steps, dtype)

        methods = {"Dr.Jit mi.render": drjit_core, "Dr.Jit mi_nest": drjit_api,
                   f"NumPy {dtype.name}": numpy_reference}
        times, results = interleaved_timings(methods, args.repeats)
        numpy_result = results[f"NumPy {dtype.name}"]
        drjit_result = results["Dr.Jit mi_nest"]

        # One more Dr.Jit run with the kernel history on, to split its wall time.
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        start = time.perf_counter()
        drjit_core()
        profiled_seconds = time.perf_counter() - start
        steady_kernels = drjit_kernels(dr)
        dr.set_flag(dr.JitFlag.KernelHistory, False)

    # ---- Agreement: the benchmark is only honest if both compute the same thing.
    pol = [name for name in numpy_result if name.startswith("pol.")]
    assert len(pol) == 16 and all(name in drjit_result for name in numpy_result)
    pol_diff = max(float(np.max(np.abs(drjit_result[n] - numpy_result[n]))) for n in pol)
    jones_diff = max(float(np.max(np.abs(drjit_result[n] - numpy_result[n])))
                     for n in ("jones.a", "jones.b", "jones.c", "jones.d"))
    y_diff = float(np.max(np.abs(drjit_result["Y"] - numpy_result["Y"])))
    order_diff = float(np.max(np.abs(drjit_result["fringe.order"] - numpy_result["fringe.order"])))
    assert numpy_result["jones.a"].dtype == dtype, "NumPy silently changed precision"

    pick = min if args.stat == "best" else statistics.median
    chosen = {name: pick(t) for name, t in times.items()}
    numpy_seconds = chosen[f"NumPy {dtype.name}"]
    ratio = numpy_seconds / chosen["Dr.Jit mi.render"]
    api_ratio = numpy_seconds / chosen["Dr.Jit mi_nest"]

    # ---- Report.
    cpu = "unknown CPU"
    if os.path.exists("/proc/cpuinfo"):
        with open("/proc/cpuinfo") as cpuinfo:
            cpu = next((line.split(":", 1)[1].strip() for line in cpuinfo
                        if line.startswith("model name")), cpu)
    field_text = "analytic twisted" if grid is None else (
        f"twisted sampled on a {args.grid_res}^3 grid (NumPy lookup: {args.grid_lookup})")
    print(f"mi_nest forward benchmark: {args.res}x{args.res} rays x {args.steps} steps, "
          f"field = {field_text}")
    print(f"machine: {cpu}, {os.cpu_count()} logical cores; Dr.Jit {dr.__version__} LLVM backend, "
          f"{dr.thread_count()} threads; NumPy {np.__version__} ({dtype.name}, 1 thread)")
    print()
    # Both statistics are shown; throughput and ratios use the one chosen with --stat.
    header = (f"{'method':<18}{'best s':>9}{'median s':>10}{'rays':>9}{'steps/ray':>11}"
              f"{'ray-steps/s':>13}{'vs NumPy':>10}")
    print(header)
    print("-" * len(header))
    for name, seconds in chosen.items():
        print(f"{name:<18}{min(times[name]):>9.4f}{statistics.median(times[name]):>10.4f}{rays:>9d}"
              f"{args.steps:>11d}{ray_steps / seconds:>13.3e}{numpy_seconds / seconds:>9.1f}x")
    print()
    if (args.res, args.steps) == (256, 256):
        verdict = ("meets" if ratio >= TARGET_RATIO else "BELOW") + f" the {TARGET_RATIO:g}x target"
    else:
        verdict = f"the {TARGET_RATIO:g}x target is defined at 256x256 rays and 256 steps"
    print(f"ratio Dr.Jit / NumPy ({args.stat} of {args.repeats}): {ratio:.1f}x with mi.render, "
          f"{api_ratio:.1f}x with mi_nest.render ({verdict})")

    # Where the Dr.Jit time goes: the first run pays tracing + LLVM compilation (or a
    # disk-cache load); steady runs pay Python tracing + the megakernel.
    compile_ms = sum(k.get("backend_time", 0.0) for k in first_kernels)
    codegen_ms = sum(k.get("codegen_time", 0.0) for k in first_kernels)
    from_disk = sum(1 for k in first_kernels if k.get("cache_disk"))
    compiled = sum(1 for k in first_kernels if not k.get("cache_hit"))
    main_kernel = max(steady_kernels, key=lambda k: k["execution_time"])
    kernel_s = main_kernel["execution_time"] / 1000.0
    print(f"Dr.Jit first run: {first_seconds:.3f} s ({len(first_kernels)} kernels: {compiled} compiled "
          f"[LLVM {compile_ms / 1000:.3f} s], {from_disk} loaded from the disk cache, "
          f"IR codegen {codegen_ms:.1f} ms)")
    print(f"Dr.Jit steady run: {profiled_seconds:.4f} s wall, of which the render kernel "
          f"({main_kernel['operation_count']} IR ops) ran {kernel_s:.4f} s "
          f"= {ray_steps / kernel_s:.3e} ray-steps/s; the rest is Python tracing, film and copies")
    print(f"NumPy per step: {numpy_seconds / args.steps * 1e3:.2f} ms for {rays} rays "
          f"({numpy_seconds / ray_steps * 1e9:.1f} ns per ray-step)")
    print()
    print(f"agreement Dr.Jit vs NumPy: max |diff| pol.* (16 channels) = {pol_diff:.2e}, "
          f"jones.* = {jones_diff:.2e}, Y = {y_diff:.2e}, fringe.order = {order_diff:.2e}")
    if grid is None:
        exact = twisted_closed_form(args, phase_rate)
        error = max(float(np.max(np.abs(drjit_result[n] - e)))
                    for n, e in zip(("jones.a", "jones.b", "jones.c", "jones.d"), exact))
        print(f"Dr.Jit vs closed-form twisted retarder: max |diff| jones.* = {error:.2e} "
              f"(midpoint rule, h = {args.depth / args.steps:.4f} mm)")
    print(f"camera check: NumPy ray entry points within {check_camera(scene, args):.1e} mm of "
          "Mitsuba's (corner pixels)")
    # float32 round-off over a few hundred steps is ~1e-5; a wrong step count or
    # step order would show up as 1e-3 or more.
    tolerance = 1e-4
    if not pol_diff < tolerance:
        print(f"ERROR: Dr.Jit and NumPy disagree by {pol_diff:.2e} (> {tolerance:g}); "
              "the timings do not compare the same work", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
