"""Fast paths of the integration methods (issue 4, item 5), timed side by side in one run.

1. The commuting disk (plane stress seen along its normal) at 512 x 512: ``linear``
   and ``auto`` (one step per chord) against ``product`` at its default step
   (0.5 mm) and at one step, with errors against a fine ``magnus4`` reference.
2. The twisted block (the shipped scene, its axes turning 180 degrees through 20 mm): the fewest steps reaching
   an error of 1e-4 in the 16 intensities for ``magnus4`` and for midpoint ``product``, against ``magnus4`` at
   4,096 steps.

    python benchmarks/methods.py [--res 512]
"""
import argparse
import time
import warnings

import numpy as np

import mi_nest
from mi_nest.physics import MEASUREMENTS


def loaded(name, res, method, step, **defines):
    scene = mi_nest.load_scene(name, res=res, spp=1, step=step, **defines)
    scene.integrator().configure(method=method)
    return scene


def timed_render(name, res, method, step, **defines):
    scene = loaded(name, res, method, step, **defines)
    mi_nest.render(scene)                           # compile
    best = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        result = mi_nest.render(scene)
        best = min(best, time.perf_counter() - start)
    return result.channels, best, scene.integrator().decide(scene)


def error(channels, reference):
    per_pixel = np.max([np.abs(channels[n] - reference[n]) for n in MEASUREMENTS], axis=0)
    return float(np.percentile(per_pixel, 99))


def commuting_disk(res):
    reference, _, _ = timed_render("disk_compression", res, "magnus4", 0.05)
    rows = []
    for label, method, step in (("product, 0.5 mm (default)", "product", 0.5), ("product, one step", "product", 6.0),
                                ("linear, one step", "linear", 6.0), ("auto", "auto", 0.5)):
        channels, seconds, decision = timed_render("disk_compression", res, method, step)
        rows.append((label, seconds, error(channels, reference), decision.step_size))
    base = rows[0][1]
    print(f"\n1. commuting disk, {res}x{res} rays (error: 99th percentile of the 16 intensities)")
    print(f"{'method':28s} {'seconds':>8s} {'error':>9s} {'step mm':>8s} {'speed-up':>9s}")
    for label, seconds, err, step in rows:
        print(f"{label:28s} {seconds:8.4f} {err:9.1e} {step:8.3g} {base / seconds:8.1f}x")


def twisted_block(target=1e-4, res=8, depth=20.0):
    reference = mi_nest.render(loaded("twisted_block", res, "magnus4", depth / 4096)).channels

    def intensity_error(method, steps):
        channels = mi_nest.render(loaded("twisted_block", res, method, depth / steps * (1 + 1e-6))).channels
        return max(float(np.max(np.abs(channels[n] - reference[n]))) for n in MEASUREMENTS)

    def fewest(method):
        low, high = 1, 1
        while intensity_error(method, high) > target:
            low, high = high, high * 2
        while low < high:                              # errors fall monotonically with the step count here
            middle = (low + high) // 2
            if intensity_error(method, middle) <= target:
                high = middle
            else:
                low = middle + 1
        return high
    magnus, midpoint = fewest("magnus4"), fewest("product")
    print(f"\n2. twisted block: fewest steps over {depth:g} mm for an error <= {target:g} in the 16 intensities")
    print(f"magnus4 {magnus} steps, product (midpoint) {midpoint} steps: {midpoint / magnus:.1f}x fewer "
          f"(target: at least 4x)")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--res", type=int, default=512)
    args = parser.parse_args()
    warnings.simplefilter("ignore", RuntimeWarning)
    commuting_disk(args.res)
    twisted_block()


if __name__ == "__main__":
    main()
