"""What sampling a network on its lattice costs an iteration: the forward pass at every node and the backward pass
of a gradient on the samples into the weights, by cooperative vectors (how the rays evaluate a network at every
step) and by matrix products on a tensor of all the nodes (how ``_NeuralField`` samples its lattice), side by side
in one process, for the MLP and the hash grid on the disk target's 64 x 64 x 11 lattice. Also checks that both give
the same samples and the same gradients.

    .venv/bin/python benchmarks/network_lattice.py --repeats 10
"""
from __future__ import annotations

import argparse
import time

import drjit as dr
import mitsuba as mi
import numpy as np

import mi_nest  # noqa: F401  (sets the variant)
from mi_nest.io.grid import grid_nodes
from mi_nest.reconstruct import FieldConfig, make_field
from reconstruction import cpu_name

# The disk target's box (mm) and its default lattice (64 nodes along the longest side).
BOX = (np.array([-20.0, -20.0, -3.0]), np.array([20.0, 20.0, 3.0]))
RESOLUTION = 64


def timed_pass(field, evaluate, positions, weights, repeats: int) -> tuple[float, list, dict]:
    """Median seconds of one forward and backward pass by ``evaluate``; the last samples and gradients."""
    parameters = field.parameters()
    seconds = []
    for _ in range(repeats + 1):
        for value in parameters.values():
            dr.enable_grad(value)
            dr.clear_grad(value)
        began = time.perf_counter()
        with dr.resume_grad():
            values = evaluate(positions)
            dr.backward(sum(dr.sum(value * weight) for value, weight in zip(values, weights)))
        gradients = {name: dr.grad(value) for name, value in parameters.items()}
        dr.eval(values, gradients)
        dr.sync_thread()
        seconds.append(time.perf_counter() - began)
    # The first pass compiles the kernels.
    return float(np.median(seconds[1:])), [np.array(v) for v in values], \
        {name: np.array(g) for name, g in gradients.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10, help="timed passes per way (after one to compile)")
    args = parser.parse_args()
    print(f"CPU: {cpu_name()}, Dr.Jit threads: {dr.thread_count()}", flush=True)
    for kind in ("mlp", "hashgrid"):
        field = make_field(FieldConfig(kind=kind, resolution=RESOLUTION), *BOX, 1.0)
        positions = mi.Point3f(grid_nodes(*BOX, field.shape).T.astype(np.float32))
        rng = np.random.default_rng(0)
        weights = [mi.Float(rng.standard_normal(int(np.prod(field.shape))).astype(np.float32)) for _ in range(5)]
        vectors, by_vectors, grad_vectors = timed_pass(field, field.network, positions, weights, args.repeats)
        tensors, by_tensors, grad_tensors = timed_pass(field, field.network_at_all, positions, weights, args.repeats)
        sample_gap = max(float(np.abs(a - b).max()) for a, b in zip(by_vectors, by_tensors))
        gradient_gap = max(float(np.abs(grad_vectors[n] - grad_tensors[n]).max() / np.abs(grad_vectors[n]).max())
                           for n in grad_vectors)
        print(f"{field.describe()}: {1000 * vectors:.1f} ms by cooperative vectors, {1000 * tensors:.1f} ms by "
              f"matrix products ({vectors / tensors:.1f} times faster); samples differ by {sample_gap:.2g} at most, "
              f"gradients by {gradient_gap:.2g} of the largest", flush=True)


if __name__ == "__main__":
    main()
