"""What the integrator refuses or warns about: open specimens, too many steps, lost unitarity, aliasing."""
from __future__ import annotations

import warnings

import mitsuba as mi
import numpy as np

from mi_nest.physics import aliasing

# Most steps a ray may take across the specimens. Beyond it float32 rounding of the steps outweighs their
# error (the disk at 6e7 steps: 10% off in retardance; at 1e-9 mm the step count overflows to none) and a
# view takes minutes.
MAX_STEPS_PER_RAY = 10 ** 6
# |J|^2 may drift this far from 1 before rk4 results are reported as unreliable.
NORM_TOLERANCE = 1e-3
# Mitsuba's analytic shapes that bound a volume (cylinder and disk are open surfaces).
CLOSED_ANALYTIC_SHAPES = ("Sphere",)

# Shapes known to be closed, by registry id and face count (checking costs a pass over the faces).
_closed_shapes = set()


class SceneSetupError(ValueError):
    """The scene cannot be rendered photoelastically (no specimen, no polariscope...)."""


def require_closed(shape: mi.Shape, shape_id: int, what: str = "specimen") -> None:
    """A specimen (or a bath) must be a closed surface, or rays that enter it never leave."""
    name = shape.id() or shape.class_name()
    holds = "a stress medium" if what == "specimen" else "a bath's liquid"
    if not shape.is_mesh():
        if shape.class_name() not in CLOSED_ANALYTIC_SHAPES:
            raise SceneSetupError(f"photoelastic: {what} '{name}' ({shape.class_name()}) is not a closed "
                                  f"surface; use a closed mesh (or a sphere) to hold {holds}")
        return
    key = (shape_id, shape.face_count())
    if key in _closed_shapes:
        return
    # Weld by position: meshes repeat vertices along creases (Mitsuba's cube does), as exact copies.
    positions = np.array(shape.vertex_positions_buffer()).reshape(-1, 3)
    _, welded = np.unique(positions, axis=0, return_inverse=True)
    faces = welded.ravel()[np.array(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)]
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    open_edges = int(np.count_nonzero(uses != 2))
    if open_edges:
        raise SceneSetupError(f"photoelastic: {what} '{name}' is not a closed mesh ({open_edges} edges not "
                              "shared by exactly two faces); rays entering it would never leave")
    _closed_shapes.add(key)


def check_steps_per_ray(diagonal: float, step: float) -> None:
    """Refuse a step that makes more than :data:`MAX_STEPS_PER_RAY` steps across specimens ``diagonal`` mm wide."""
    steps = diagonal / step
    if steps > MAX_STEPS_PER_RAY:
        raise SceneSetupError(f"photoelastic: step_size {step:g} mm makes up to {steps:.3g} steps per ray across "
                              f"the specimens (their bounding box diagonal is {diagonal:.4g} mm); the most is "
                              f"{MAX_STEPS_PER_RAY:.0e}: use a step_size of at least "
                              f"{diagonal / MAX_STEPS_PER_RAY:.2g} mm")


def warn_if_not_unitary(norm_error: float, step_size: float) -> None:
    """Warn when rk4's largest ``| |J|^2 - 1 |`` over a render passes :data:`NORM_TOLERANCE`."""
    if norm_error > NORM_TOLERANCE:
        warnings.warn(
            f"photoelastic: rk4 is not unitary here: | |J|^2 - 1 | reaches {norm_error:.3g} (step_size "
            f"{step_size:g} mm). RK4 shrinks |J|^2 by about x^6/72 per step and blows up when the phase x "
            f"per step exceeds 2 sqrt(2) = 2.83 rad; use a smaller step_size, or 'product'/'magnus4'",
            RuntimeWarning, stacklevel=3)


def check_aliasing(order: np.ndarray, length: np.ndarray) -> aliasing.FringeAliasing:
    """Measure the fringe density of an image's order channel; warn if the intensities alias."""
    report = aliasing.fringe_aliasing(order, length > 0)
    if report.aliases:
        warnings.warn(f"photoelastic: {report.describe()}: the intensities alias there. Render at "
                      f"{report.resolution_factor}x the resolution, or supersample (spp) to average the "
                      "fringes within each pixel as a camera does", RuntimeWarning, stacklevel=3)
    return report


def refuse_refraction(setup, what: str) -> None:
    """What cannot follow refracted paths yet is refused, not traced straight by mistake."""
    if setup.refracting:
        raise SceneSetupError(f"photoelastic: {what} through refracting surfaces is not available yet (renders and "
                              "ray batches are); drop the specimens' and baths' dielectric BSDFs for index-matched "
                              "straight rays")
