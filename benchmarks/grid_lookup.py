"""What a grid field's trilinear lookup costs, by storage: the floor under the grid march's ray-steps/s.

Marches 256 x 256 rays through a 64^3 grid of random values, 256 lookups per
ray in one symbolic loop (the shape of ``benchmarks/forward.py --field grid``),
and sums the channels so that nothing is optimised away. Compares the loop
without a lookup (a closed-form stand-in with as many outputs), ``mi.Texture3f``
with 6 channels (what ``GridField`` stores; Dr.Jit pads them to 8), 4 and 2
channels, a half-precision ``Texture3f16`` with 6, and a hand-written trilinear
lookup of 2 channels (what one view's projected stress would need: for an
orthographic view every ray shares its transverse frame) with each node's +x
neighbour stored beside it (``XPairGrid``). The best of ``--repeats`` runs,
interleaved.

    python benchmarks/grid_lookup.py
"""
from __future__ import annotations

import argparse
import time

import drjit as dr
import mitsuba as mi
import numpy as np

import mi_nest  # noqa: F401  (the variant)

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


class XPairGrid:
    """Two channels (a view's projected stress ``(p, q)``) stored with each node's +x neighbour beside it: a
    trilinear lookup is four gathers of one 4-float packet (the Texture3f's is eight of 8 floats)."""

    def __init__(self, values: np.ndarray):
        nz, ny, nx, _ = values.shape
        pairs = np.concatenate([values, values[:, :, np.minimum(np.arange(nx) + 1, nx - 1)]], axis=-1)
        self.flat = mi.Float(np.ascontiguousarray(pairs, dtype=np.float32).ravel())
        self.shape = (nx, ny, nz)

    def eval(self, p: mi.Point3f) -> list[mi.Float]:
        nx, ny, nz = self.shape
        cells, fractions = [], []
        for coordinate, n in zip((p.x, p.y, p.z), self.shape):
            t = dr.clip(coordinate * (n - 1), 0.0, n - 1.0)
            cell = dr.minimum(mi.UInt32(t), n - 2)
            cells.append(cell)
            fractions.append(t - mi.Float(cell))
        fx, fy, fz = fractions
        base = (cells[2] * ny + cells[1]) * nx + cells[0]
        corner = [dr.gather(mi.Vector4f, self.flat, base + offset) for offset in (0, nx, nx * ny, nx * ny + nx)]
        along_x = [dr.fma(fx, mi.Vector2f(c.z, c.w) - mi.Vector2f(c.x, c.y), mi.Vector2f(c.x, c.y)) for c in corner]
        near = dr.fma(fy, along_x[1] - along_x[0], along_x[0])
        far = dr.fma(fy, along_x[3] - along_x[2], along_x[2])
        value = dr.fma(fz, far - near, near)
        return [value.x, value.y]


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
    cases = {"no lookup (closed form, 6 outputs)": (lambda p: [p.x * p.z + c for c in range(6)], 6),
             "Texture3f, 6 channels (GridField)": (texture(6).eval, 6),
             "Texture3f, 4 channels": (texture(4).eval, 4),
             "Texture3f, 2 channels": (texture(2).eval, 2),
             "Texture3f16 (half), 6 channels": (half.eval, 6),
             "x-pair grid, 2 channels (manual)": (XPairGrid(values[..., :2]).eval, 2)}
    # The hand-written lookup must agree with the texture's (whose [0, 1] spans texel edges, not nodes).
    pairs, two = XPairGrid(values[..., :2]), texture(2)
    points = mi.Point3f(np.random.default_rng(1).random((3, 1000)).astype(np.float32))
    nodes = mi.Vector3f(args.nodes)
    disagreement = max(float(dr.max(dr.abs(a - b))[0]) for a, b in
                       zip(pairs.eval(points), two.eval(points * (nodes - 1) / nodes + 0.5 / nodes)))
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
          f"the x-pair lookup agrees with the texture's within {disagreement:.1e}")
    for name, seconds in best.items():
        print(f"  {name:36s} {1000 * seconds:7.1f} ms  {rays * args.steps / seconds:.3e} lookups/s")


if __name__ == "__main__":
    main()
