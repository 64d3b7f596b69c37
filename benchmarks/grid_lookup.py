"""What a grid field's trilinear lookup costs, by storage: the floor under the grid march's ray-steps/s.

Marches 256 x 256 rays through a 64^3 grid of random values, 256 lookups per
ray in one symbolic loop (the shape of ``benchmarks/forward.py --field grid``),
and sums the channels so that nothing is optimised away. Compares the loop
without a lookup (a closed-form stand-in with as many outputs), ``mi.Texture3f``
with 6 channels (what ``GridField`` stores; Dr.Jit pads them to 8), 4 and 2
channels, a half-precision ``Texture3f16`` with 6, and the hand-written trilinear
lookup of 2 channels with each node's in-plane face stored in its bilinear form
(two 8-float packets per lookup) that an orthographic render of a grid uses
(``ProjectedGrid``: every ray of such a view shares its transverse frame). The best of ``--repeats`` runs, interleaved.

    python benchmarks/grid_lookup.py
"""
from __future__ import annotations

import argparse
import time

import drjit as dr
import mitsuba as mi
import numpy as np

import mi_nest  # noqa: F401  (the variant)
from mi_nest.fields.grid import GridField, ProjectedGrid
from mi_nest.io.grid import StressGrid

from reconstruction import cpu_name


def lookup_loop(lookup, channels, rays, steps):
    """A function running ``steps`` lookups per ray and returning the seconds it took."""
    index = dr.arange(mi.UInt32, rays)
    side = int(round(rays ** 0.5))
    x = mi.Float(index % side) / side * 0.8 + 0.1
    y = mi.Float(index // side) / side * 0.8 + 0.1

    def body(i, total):
        z = (mi.Float(i) + 0.5) / steps
        values = lookup(mi.Point3f(x, y, z))
        return i + 1, total + sum(mi.Float(values[c]) * (c + 1) for c in range(channels))

    def run():
        start = time.perf_counter()
        _, total = dr.while_loop((mi.UInt32(0), mi.Float(0)), lambda i, total: i < steps, body)
        dr.eval(total)
        dr.sync_thread()
        return time.perf_counter() - start
    return run


def face_grid(values: np.ndarray) -> ProjectedGrid:
    """The first two of ``values``'s channels as :class:`ProjectedGrid` stores and looks them up (each node's
    face in its z plane in bilinear form: two gathers of one 8-float packet), over the unit cube."""
    unit = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    return ProjectedGrid(GridField(StressGrid(values, np.zeros(3), np.ones(3))), unit, unit[-1:] + unit[:-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--res", type=int, default=256, help="rays per side")
    parser.add_argument("--steps", type=int, default=256)
    parser.add_argument("--nodes", type=int, default=64, help="grid nodes per axis")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    rays = args.res * args.res
    values = np.random.default_rng(0).standard_normal((args.nodes,) * 3 + (6,)).astype(np.float32)
    options = dict(filter_mode=dr.FilterMode.Linear, wrap_mode=dr.WrapMode.Clamp)

    def texture(channels):
        return mi.Texture3f(mi.TensorXf(np.ascontiguousarray(values[..., :channels])), **options)
    half = dr.llvm.ad.Texture3f16(dr.llvm.ad.TensorXf16(values.astype(np.float16)), **options)
    faces, two = face_grid(values), texture(2)
    cases = {"no lookup (closed form, 6 outputs)": (lambda p: [p.x * p.z + c for c in range(6)], 6),
             "Texture3f, 6 channels (GridField)": (texture(6).eval, 6),
             "Texture3f, 4 channels": (texture(4).eval, 4),
             "Texture3f, 2 channels": (texture(2).eval, 2),
             "Texture3f16 (half), 6 channels": (half.eval, 6),
             "face grid, 2 channels (ProjectedGrid)": (faces.eval, 2)}
    # The hand-written lookup must agree with the texture's (whose [0, 1] spans texel edges, not nodes).
    points = mi.Point3f(np.random.default_rng(1).random((3, 1000)).astype(np.float32))
    nodes = mi.Vector3f(args.nodes)
    disagreement = max(float(dr.max(dr.abs(a - b))[0]) for a, b in
                       zip(faces.eval(points), two.eval(points * (nodes - 1) / nodes + 0.5 / nodes)))
    assert disagreement < 1e-4, disagreement
    runs = {name: lookup_loop(lookup, channels, rays, args.steps) for name, (lookup, channels) in cases.items()}
    for run in runs.values():
        run()       # compile
    seconds = {name: [] for name in runs}
    for _ in range(args.repeats):
        for name, run in runs.items():
            seconds[name].append(run())
    best = {name: min(times) for name, times in seconds.items()}
    print(f"{cpu_name()}; {args.res}^2 rays x {args.steps} lookups in a {args.nodes}^3 grid, best of {args.repeats}; "
          f"the face grid's lookup agrees with the texture's within {disagreement:.1e}")
    for name, seconds in best.items():
        print(f"  {name:40s} {1000 * seconds:7.1f} ms  {rays * args.steps / seconds:.3e} lookups/s")


if __name__ == "__main__":
    main()
