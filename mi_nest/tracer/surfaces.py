"""Which surfaces refract: a smooth ``dielectric`` on a specimen or a bath, its index ratio, and baths that must
hold their specimens whole (docs/physics.md section 8; the walk that bends at them is ``refraction.py``)."""
from __future__ import annotations

import math

import mitsuba as mi
import numpy as np

from mi_nest import occupancy

from .guards import SceneSetupError

# Mitsuba's BSDF classes a surface may carry, and why the others that transmit are refused.
INTERFACE_BSDF = "SmoothDielectric"
REFUSED_BSDFS = {
    "RoughDielectric": "a rough dielectric scatters the light it transmits, which no Jones product follows; "
                       "use a smooth 'dielectric'",
    "ThinDielectric": "a thin dielectric sheet has no inside to hold a stress field or a bath; use a closed "
                      "shape with a 'dielectric'",
}


def interface_ratio(shape: mi.Shape) -> float | None:
    """``int_ior / ext_ior`` of ``shape``'s surface, or None where it carries no dielectric."""
    bsdf = shape.bsdf()
    if bsdf is None:
        return None
    kind = bsdf.class_name()
    name = shape.id() or shape.class_name()
    if kind in REFUSED_BSDFS:
        raise SceneSetupError(f"photoelastic: the surface of '{name}' is a {kind}: {REFUSED_BSDFS[kind]}")
    if kind != INTERFACE_BSDF:
        return None
    ratio = float(mi.traverse(bsdf)["eta"])
    if not (math.isfinite(ratio) and ratio > 0):
        raise SceneSetupError(f"photoelastic: the dielectric surface of '{name}' has int_ior / ext_ior = {ratio}; "
                              "give both indices as positive numbers (or a material name Mitsuba knows)")
    return ratio


# Specimen and bath pairs known not to cut each other, by registry ids and bounding boxes: the check traces
# rays, and a scene is set up again for every render pass and training batch.
_apart_pairs = set()


def require_apart(scene: mi.Scene, specimen: mi.Shape, bath: mi.Shape, samples: int = 512) -> None:
    """A bath's surface must not cut a specimen: the specimen lies wholly inside it or wholly outside."""
    key = tuple((occupancy.shape_id(shape), str(shape.bbox()))
                for shape in (specimen, bath))
    if key in _apart_pairs:
        return
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(0, samples)
    points = specimen.sample_position(0.0, sampler.next_2d()).p
    inside = occupancy.inside(scene, [bath], np.array(points).T)
    if inside.any() and not inside.all():
        raise SceneSetupError(f"photoelastic: the surface of bath '{bath.id() or bath.class_name()}' cuts specimen "
                              f"'{specimen.id() or specimen.class_name()}' ({int(inside.sum())} of {samples} points "
                              "of the specimen's surface inside it); a bath must hold its specimens whole")
    _apart_pairs.add(key)
