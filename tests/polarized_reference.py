"""Render stacks of Mitsuba's own polarising BSDFs in ``llvm_ad_mono_polarized``.

An independent reference for ``tests/test_independent_renderer.py``: it never
imports mi_nest and speaks only Mitsuba's native parameters, so every
convention mapping lives (and is checked) in the test, not here.

Usage (in its own process: Mitsuba variants cannot be mixed in one process)::

    python polarized_reference.py REQUEST.json RESULT.json

``REQUEST.json`` maps stack names to lists of elements in the order light
meets them, each ``{"type": "polarizer" | "retarder", "theta": deg,
"delta": deg (retarder only), "rotate": deg (optional)}`` or a glass block
``{"type": "block", "int_ior": n, "tilt": deg, "half_thickness": mm}`` (a cube
with Mitsuba's smooth ``dielectric`` BSDF, ``ext_ior`` 1, turned by ``tilt``
about the x axis, 20 mm past the elements before it). ``theta`` and
``delta`` are passed to the BSDF unchanged; ``rotate`` turns the element's
rectangle about the world z axis (from +x towards +y), which turns its
optical axes geometrically, whatever sign convention ``theta`` follows.
``RESULT.json`` maps each name to the mean pixel intensity of its render.

Geometry: an unpolarised area light (radiance 1) at z = -50 facing +z, one
20 x 20 rectangle per element at z = -10, -9, ... (normal +z, local U = +x,
V = +y before ``rotate``), and an orthographic camera at z = +100 looking
along -z with up +y. Light therefore travels along +z through the stack,
along every rectangle's normal; image right is +x and image up is +y.
"""
import json
import os
import sys

LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
FILM_SIZE = 2
# Samples per pixel of a stack with a block: Mitsuba's dielectric chooses reflection or transmission at random.
BLOCK_SPP = 8192


def _scene_dict(mi, elements):
    T = mi.ScalarTransform4f
    scene = {
        "type": "scene",
        # Each element is one path vertex; Russian roulette (default from depth
        # 5 on) would randomly kill or boost these deterministic paths.
        # A block adds two crossings, and internal reflections (ghosts) a few more.
        "integrator": {"type": "path", "max_depth": len(elements) + 8,
                       "rr_depth": len(elements) + 100},
        "sensor": {
            "type": "orthographic",
            "to_world": T().look_at(origin=[0, 0, 100], target=[0, 0, 0], up=[0, 1, 0])
                        @ T().scale([2, 2, 1]),
            "film": {"type": "hdrfilm", "width": FILM_SIZE, "height": FILM_SIZE,
                     "pixel_format": "luminance", "rfilter": {"type": "box"}},
            "sampler": {"type": "stratified", "sample_count": 1, "jitter": False},
        },
        "light": {"type": "rectangle",
                  "to_world": T().translate([0, 0, -50]) @ T().scale(20),
                  "emitter": {"type": "area", "radiance": 1.0}},
    }
    z = -10.0
    for index, element in enumerate(elements):
        element = dict(element)
        rotate = float(element.pop("rotate", 0.0))
        kind = element.pop("type")
        if kind == "block":
            half = float(element.pop("half_thickness"))
            scene[f"element_{index:02d}"] = {
                "type": "cube",
                "to_world": T().translate([0, 0, z + 10.0]) @ T().rotate([1, 0, 0], float(element.pop("tilt")))
                            @ T().scale([15, 15, half]),
                "bsdf": {"type": "dielectric", "int_ior": float(element.pop("int_ior")), "ext_ior": 1.0},
            }
            if element:
                raise ValueError(f"unknown element keys {sorted(element)}")
            z += 20.0
            continue
        if kind not in ("polarizer", "retarder"):
            raise ValueError(f"unknown element type {kind!r}")
        bsdf = {"type": kind, "theta": float(element.pop("theta"))}
        if kind == "retarder":
            bsdf["delta"] = float(element.pop("delta"))
        if element:
            raise ValueError(f"unknown element keys {sorted(element)}")
        scene[f"element_{index:02d}"] = {
            "type": "rectangle",
            "to_world": T().translate([0, 0, z]) @ T().rotate([0, 0, 1], rotate) @ T().scale(10),
            "bsdf": bsdf,
        }
        z += 1.0
    return scene


def render_stacks(stacks):
    """``{name: intensity}`` for ``{name: [element, ...]}``."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
        # Same workaround as mi_nest: Dr.Jit 1.5 needs LLVM >= 17 to run.
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19
    import mitsuba as mi
    mi.set_variant("llvm_ad_mono_polarized")

    results = {}
    for name, elements in stacks.items():
        stochastic = any(element["type"] == "block" for element in elements)
        image = mi.render(mi.load_dict(_scene_dict(mi, elements)), spp=BLOCK_SPP if stochastic else 1).numpy()
        results[name] = float(image.mean())
        spread = float(image.max() - image.min())
        if spread > 1e-5 and not stochastic:
            raise RuntimeError(f"{name}: image should be uniform, spread {spread}")
    return results


def main(argv):
    if len(argv) != 3:
        raise SystemExit(f"usage: {argv[0]} REQUEST.json RESULT.json")
    with open(argv[1]) as f:
        stacks = json.load(f)
    results = render_stacks(stacks)
    with open(argv[2], "w") as f:
        json.dump(results, f, indent=1)


if __name__ == "__main__":
    main(sys.argv)
