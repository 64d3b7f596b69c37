"""The L1 loss and its backward: this version (one upload of the targets, one reduction) against the one before
(16 uploads, 16 reductions), side by side in one run. 2048 pixels x 4 rays, 16 channels, half the pixels
weighted out; the median of 35 evaluations after 5, over three alternating rounds. Also checks that both give
the same loss and gradient.

    python benchmarks/loss.py
"""
import statistics
import time

import drjit as dr
import mitsuba as mi
import numpy as np

import mi_nest  # noqa: F401  (the variant)
from mi_nest.arrays import device_array
from mi_nest.reconstruct.losses import intensities, l1_loss

from reconstruction import cpu_name

PIXELS, SAMPLES = 2048, 4


def before(q, targets, pixel_samples=1, weights=None):
    """``l1_loss`` as it was before issue 22."""
    targets = np.asarray(targets, dtype=np.float32)
    total = 0.0
    for channel, predicted in enumerate(intensities(q)):
        if pixel_samples > 1:
            predicted = dr.block_sum(predicted, pixel_samples) / pixel_samples
        error = dr.abs(predicted - device_array(mi.Float, targets[:, channel]))
        total = total + dr.sum(error if weights is None else error * weights)
    count = len(targets) if weights is None else dr.maximum(dr.sum(weights), 1.0)
    return total / (count * targets.shape[1])


def measure(loss, rays, targets, weights):
    """Median seconds of loss plus backward, and the last loss and gradient."""
    seconds = []
    for _ in range(40):
        q = tuple(mi.Float(x) for x in rays)
        dr.enable_grad(q)
        dr.sync_thread()
        start = time.perf_counter()
        with dr.resume_grad():
            value = loss(q, targets, SAMPLES, weights)
            dr.backward(value)
        gradient = [dr.grad(x) for x in q]
        dr.eval(gradient)
        dr.sync_thread()
        seconds.append(time.perf_counter() - start)
    return statistics.median(seconds[5:]), float(value[0]), np.stack([np.array(g) for g in gradient])


def main():
    rng = np.random.default_rng(0)
    rays = rng.normal(size=(4, PIXELS * SAMPLES)).astype(np.float32)
    rays /= np.linalg.norm(rays, axis=0)
    targets = rng.random((PIXELS, 16)).astype(np.float32)
    weights = mi.Float(rng.integers(0, 2, PIXELS).astype(np.float32))
    print(f"{cpu_name()}; {PIXELS} pixels x {SAMPLES} rays, 16 channels")
    for _ in range(3):
        old, old_value, old_gradient = measure(before, rays, targets, weights)
        new, new_value, new_gradient = measure(l1_loss, rays, targets, weights)
        print(f"before {1000 * old:.2f} ms, now {1000 * new:.2f} ms, ratio {old / new:.2f}x; loss {old_value:.7f} "
              f"and {new_value:.7f}, gradients differ by at most {np.abs(old_gradient - new_gradient).max():.1e}")


if __name__ == "__main__":
    main()
