"""The grid smoothness penalty and its gradient: the custom op (gradient gathered per node) against automatic
differentiation of the same penalty (each pair's derivative scattered by atomics), side by side in one run.

On the disk target's finest grid (64 x 64 x 11 nodes, 5 components), with and without the Charbonnier edge; the
median of ``--repeats`` evaluations of penalty plus backward, each synchronised.

    python benchmarks/smoothness.py
"""
import argparse
import statistics
import time

import drjit as dr
import mitsuba as mi
import numpy as np

import mi_nest  # noqa: F401  (the variant)
from mi_nest.reconstruct.fields import _neighbour_pairs, _Smoothness

from reconstruction import cpu_name


def automatic(values, pairs, per_length, weight, edge):
    first, second = pairs
    squared = dr.square((dr.gather(mi.Float, values, first) - dr.gather(mi.Float, values, second)) * per_length)
    plain = squared if edge is None else 2.0 * squared / (dr.sqrt(1.0 + squared / dr.opaque(mi.Float, edge ** 2)) + 1.0)
    return dr.opaque(mi.Float, weight) * dr.mean(plain)


def custom(values, pairs, per_length, weight, edge, shape):
    return dr.custom(_Smoothness, values, pairs, shape, per_length, dr.opaque(mi.Float, weight),
                     None if edge is None else dr.opaque(mi.Float, edge ** 2))


def seconds(evaluate, values, repeats):
    times = []
    for _ in range(repeats + 1):
        parameter = mi.Float(values)
        dr.enable_grad(parameter)
        dr.sync_thread()
        start = time.perf_counter()
        with dr.resume_grad():
            dr.backward(evaluate(parameter))
        dr.eval(dr.grad(parameter))
        dr.sync_thread()
        times.append(time.perf_counter() - start)
    return statistics.median(times[1:])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    shape, per_length = (64, 64, 11), 63.0
    pairs = _neighbour_pairs(shape)
    values = mi.Float(np.random.default_rng(0).normal(size=int(np.prod(shape)) * 5).astype(np.float32))
    print(f"{cpu_name()}; grid {shape}, 5 components, {dr.width(pairs[0])} neighbour pairs")
    for edge in (None, 0.5):
        slow = seconds(lambda v: automatic(v, pairs, per_length, 0.1, edge), values, args.repeats)
        fast = seconds(lambda v: custom(v, pairs, per_length, 0.1, edge, shape), values, args.repeats)
        print(f"edge {edge}: automatic {1000 * slow:.2f} ms, custom op {1000 * fast:.2f} ms, ratio {slow / fast:.2f}x")


if __name__ == "__main__":
    main()
