"""The walk that bends at refracting surfaces (docs/physics.md section 8); ``surfaces.py`` says which
surfaces refract.

A shape whose BSDF is Mitsuba's smooth ``dielectric`` is an interface with the
index ratio ``int_ior / ext_ior`` (Mitsuba's ``eta``): a specimen's own surface,
or a bath (a closed shape without a stress medium: an immersion tank's liquid
or wall). Without one, a specimen is index-matched and its rays run straight
(``walk.py``). As in Mitsuba, each surface says what lies
on either side of it: nested interfaces must agree (a specimen's ``ext_ior`` is
its bath's ``int_ior``).

The walk follows the path the light takes to each camera pixel, traced from
the camera: Snell's law at each interface, the Fresnel transmission (flux
amplitudes) as a Jones matrix in the ray's transverse frame, which is carried
across without twist; where the traced ray cannot leave (total internal
reflection) it is reflected with the reflection's phases; a ray trapped past
``max_crossings``, or sent back towards the camera's side, brings no light.
That transmitted path is deterministic and differentiable. Partial reflections
make the ghosts: with ``bounces`` the walk instead samples at each crossing
where the light is partly reflected, reflection or transmission, and weights
the chosen Fresnel matrix by the choice's probability (the tracer adds the
ghosts' intensities to the transmitted path's). The stress march runs as
before on each straight segment inside a specimen. The camera's polariscope elements act in
its frame; the light's face the camera, so a bent path's matrix is turned at
the light by the path's geometric rotation (:func:`sheet_rotation`). A spectral
march follows one path for all its wavelengths (the indices do not depend on
the wavelength here) with one path matrix per wavelength, and its replay
back-propagates each wavelength's adjoint into the one march of the lanes.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import drjit as dr
import mitsuba as mi

from mi_nest import occupancy
from mi_nest.physics import interface, jones, projection, su2

from .segment import Segment, equal_steps
from .spectral import lane_count, split_lanes

if TYPE_CHECKING:
    from .setup import SceneSetup

class RefractedPath(NamedTuple):
    """What the refracted walk gives per ray; a spectral march's (``spectral.py``) at each of its wavelengths in
    ``lanes``, the first of which are ``jones`` and ``stress``."""
    jones: jones.Biquaternion   # the whole path's Jones matrix, interfaces included (light order)
    stress: su2.Quaternion      # the product of the specimens' segments alone
    fringe: tuple               # summed (b, c) of the step generators (the fringe-order channel)
    blocked: mi.Bool            # an opaque shape stops it, or it misses a finite light panel
    length: mi.Float            # mm inside specimens
    exit_point: mi.Point3f      # where it left the last interface
    exit_direction: mi.Vector3f  # and in which direction (traced from the camera)
    interfaces: mi.UInt32       # interfaces crossed or reflected at
    sheet_rotation: mi.Float    # radians from the carried frame to the light's sheets (sheet_rotation)
    reflections: mi.UInt32      # partial reflections taken (sampled walks only)
    lanes: tuple                # ((jones, stress) of each wavelength)


class Hit(NamedTuple):
    """One crossing of the walk: the segment marched up to it and what the surface there does."""
    marched: mi.Bool            # the segment before it ran inside a specimen
    steps: mi.UInt32
    h: mi.Float
    chord: mi.Float
    blocked: mi.Bool            # an opaque shape
    bend: mi.Bool               # a dielectric surface
    partial: mi.Bool            # where the walk took its partial reflection (sampled walks only)
    matrix: jones.Biquaternion  # its Jones matrix in the carried frame (the identity where it does not bend)
    direction: mi.Vector3f      # the traced ray's direction after it
    u: mi.Vector3f              # and its carried frame
    v: mi.Vector3f
    medium: mi.UInt32           # the specimen medium after it (0 outside)
    launch: mi.Point3f          # where the next query starts


# Partial reflections followed per ghost path unless a scene says otherwise: following more changes fewer than 1%
# of the specimen's pixel values by more than one 8-bit level (experiments/ghosts.py, docs/refraction.md).
DEFAULT_MAX_BOUNCES = 4
# Where a sampled walk may follow a partial reflection, the share of its rays that do. Ghost paths are weak
# (R^2 ~ 0.2% of the light at n = 1.55 at normal incidence) but every crossing branches. Fresnel-guided shares
# (the crossing's mean reflectance within [0.1, 0.9], [0.25, 0.75] or [0.35, 0.65]) were measured against this
# even split on the disk at 30 degrees and edge-on and on the kitten: pixel noise from 34% higher to 17% lower,
# no better overall than the simplest choice.
REFLECTION_PROBABILITY = 0.5
# The choice's value where no partial reflection may be taken (no bounces left): transmitted, weight 1.
NO_CHOICE = 2.0


def reflection_choice(seeds: mi.UInt32, crossings: mi.UInt32, reflections: mi.UInt32,
                      bounces: int) -> mi.Float | None:
    """A uniform number per ray and crossing that picks a partial reflection below ``REFLECTION_PROBABILITY``;
    ``NO_CHOICE`` once ``bounces`` are taken; None for a walk that follows the transmitted path (no bounces)."""
    if bounces == 0:
        return None
    # The high bit keeps these apart from the jitter's streams (sample_tea_32(seeds, crossings)).
    uniform = mi.sample_tea_float32(seeds, crossings | 0x80000000)
    return dr.select(reflections < bounces, uniform, NO_CHOICE)


def _query(scene, launch, d, reach, ray, active):
    return scene.ray_intersect(mi.Ray3f(launch, d, reach, ray.time, ray.wavelengths), ray_flags=mi.RayFlags.Minimal,
                               coherent=False, active=active)


def _crossing(si: mi.SurfaceInteraction3f, origin: mi.Point3f, d: mi.Vector3f, u: mi.Vector3f, v: mi.Vector3f,
              medium: mi.UInt32, setup: SceneSetup, step_size: float, active: mi.Bool,
              choice: mi.Float | None = None) -> Hit:
    """The geometry and optics of one crossing, the same in the primal walk and its replay; with ``choice``
    (:func:`reflection_choice`) a partial reflection may be taken instead of the transmission, each weighted
    by the inverse square root of its probability (intensities are quadratic in the matrix)."""
    hit = active & si.is_valid()
    shape = dr.reinterpret_array(mi.UInt32, si.shape)
    hit_medium = dr.gather(mi.UInt32, setup.medium_of_shape, shape, hit)
    ratio = dr.gather(mi.Float, setup.ratio_of_shape, shape, hit)
    bend = hit & (ratio > 0)
    entering = dr.dot(si.n, d) < 0
    chord = dr.norm(si.p - origin)
    marched = hit & (medium != 0)
    steps, h = equal_steps(chord, marched, step_size)
    # The traced ray goes from index n to n * step; the light the other way.
    step = dr.select(entering, ratio, dr.rcp(dr.maximum(ratio, 1e-30)))
    turned, cos_traced, total = interface.refract(d, si.n, mi.Float(1.0), step)
    turned = mi.Vector3f(turned)
    s_axis = mi.Vector3f(interface.s_axis(d, si.n, u))
    tau_s, tau_p = interface.transmitted_flux_amplitudes(dr.abs(dr.dot(turned, si.n)),
                                                         dr.rcp(dr.maximum(step, 1e-30)))
    phi_s, phi_p = interface.reflection_phases(cos_traced, step)
    x = (dr.select(total, dr.cos(phi_s), tau_s), dr.select(total, dr.sin(phi_s), 0.0))
    y = (dr.select(total, dr.cos(phi_p), tau_p), dr.select(total, dr.sin(phi_p), 0.0))
    partial = mi.Bool(False)
    if choice is not None:
        chosen = bend & ~total & (choice < 1.0)
        partial = chosen & (choice < REFLECTION_PROBABILITY)
        weight = dr.select(chosen, dr.rsqrt(dr.select(partial, REFLECTION_PROBABILITY,
                                                      1.0 - REFLECTION_PROBABILITY)), 1.0)
        # Reflected on the traced ray's side: the light meets it at the same angle from the same medium.
        r_s, r_p = interface.reflected_amplitudes(cos_traced, step)
        x = (weight * dr.select(partial, r_s, x[0]), weight * x[1])
        y = (weight * dr.select(partial, r_p, y[0]), weight * y[1])
        turned = dr.select(partial, mi.Vector3f(interface.reflect(d, si.n)), turned)
    matrix = _where_biquaternion(bend, jones.diattenuator(x, y, interface.s_angle(u, v, s_axis)))
    new_d = dr.select(bend, turned, d)
    # Reflected (totally or partly), the ray stays on its side of the surface.
    stays = bend & (total | partial)
    return Hit(marched, steps, h, chord, hit & (hit_medium == 0) & ~bend, bend,
               partial, matrix, new_d,
               dr.select(bend, mi.Vector3f(interface.transported(u, d, turned, s_axis)), u),
               dr.select(bend, mi.Vector3f(interface.transported(v, d, turned, s_axis)), v),
               dr.select(hit & (hit_medium != 0) & ~stays, dr.select(entering, hit_medium, 0), medium),
               occupancy.past_surface(si, new_d))


def sheet_rotation(first: mi.Vector3f, last: mi.Vector3f, right: mi.Vector3f, u: mi.Vector3f,
                   v: mi.Vector3f) -> mi.Float:
    """The angle (radians, from ``u`` towards ``v``) of the light's sheets in a bent path's carried frame
    ``(u, v)`` at its end.

    The sheets (the panel's polariser and waveplate) face the camera: a ray that
    leaves them obliquely sees their axes as the camera's frame turned by the
    shortest rotation from the ray's first direction to its last, which is the
    frame every straight ray uses. The frame carried along the bent path differs
    from it by the path's geometric rotation (the solid angle its directions
    enclose): zero for any path in one plane.
    """
    a, b = -first, -last
    axis = dr.cross(a, b)
    cosine = dr.dot(a, b)
    turned = right * cosine + dr.cross(axis, right) + axis * (dr.dot(axis, right) / dr.maximum(1.0 + cosine, 1e-6))
    return dr.atan2(dr.dot(turned, v), dr.dot(turned, u))


def _advance(si, crossing, origin, launch, reach, active):
    """The walk's state past a crossing: direction, frame, medium, segment origin, next query (and whether
    anything was hit)."""
    hit = active & si.is_valid()
    return (crossing.direction, crossing.u, crossing.v, crossing.medium, dr.select(hit, si.p, origin),
            dr.select(hit, crossing.launch, launch), dr.select(hit, dr.inf, reach), hit)


def _start(ray, setup):
    d = mi.Vector3f(ray.d)
    u, v = projection.transverse_basis(-d, setup.right)
    return d, mi.Vector3f(u), mi.Vector3f(v)


@dr.syntax
def trace(scene: mi.Scene, ray: mi.Ray3f, setup: SceneSetup, method, step_size: float, seeds: mi.UInt32,
          active: mi.Bool, max_crossings: int, bounces: int = 0) -> RefractedPath:
    """Follow each camera ray through every interface and specimen; see the module's docstring. With
    ``bounces``, sample a path of up to that many partial reflections (the Jones matrix weighted by the inverse
    square root of its probability)."""
    d, u, v = _start(ray, setup)
    origin = mi.Point3f(ray.o)
    launch = mi.Point3f(ray.o)
    reach = mi.Float(ray.maxt)
    medium = mi.UInt32(0)
    state, fringe = method.trace_start()
    # One path matrix and stress product per wavelength: the path, its interfaces and lookups are shared.
    lanes = lane_count(method)
    total = (jones.from_quaternion(su2.identity(mi.Float(0))),) * lanes
    stress = (su2.identity(mi.Float(0)),) * lanes
    blocked = mi.Bool(False)
    length = mi.Float(0)
    crossings = mi.UInt32(0)
    interfaces = mi.UInt32(0)
    reflections = mi.UInt32(0)
    active = mi.Bool(active)

    while dr.hint(active, exclude=[method, ray, scene, seeds, setup]):
        si = _query(scene, launch, d, reach, ray, active)
        # One more surface than the limit allows (trapped by total reflection): it never reaches the light.
        trapped = active & si.is_valid() & (crossings >= max_crossings)
        blocked |= trapped
        active &= ~trapped
        crossing = _crossing(si, origin, d, u, v, medium, setup, step_size, active,
                             reflection_choice(seeds, crossings, reflections, bounces))
        segment = Segment(crossing.steps, crossing.h, medium, origin, d, setup.frame_coefficients(u, v),
                               mi.sample_tea_32(seeds, crossings)[0])
        state, fringe = method.trace((state, fringe), segment, setup)
        length += dr.select(crossing.marched, crossing.chord, 0.0)
        blocked |= crossing.blocked
        # At an interface, the stress product since the last one joins the path's matrix, then the interface.
        total, stress = _joined(total, stress, method.finish(state), crossing.matrix, crossing.bend)
        state = _where(crossing.bend, method.trace_start()[0], state)
        interfaces += dr.select(crossing.bend, 1, 0)
        reflections += dr.select(crossing.partial, 1, 0)
        d, u, v, medium, origin, launch, reach, hit = _advance(si, crossing, origin, launch, reach, active)
        crossings += 1
        active &= hit & ~blocked

    # The light's sheets lie in the camera's frame turned straight onto the last direction; the frame carried
    # along the bent path has turned from it by the path's geometric rotation.
    rotation = sheet_rotation(mi.Vector3f(ray.d), d, setup.right, u, v)
    total, stress = _joined(total, stress, method.finish(state), jones.from_quaternion(su2.rotator(rotation)))
    # Bent past a finite light panel's edge, or sent back towards the camera's side (the panel lies behind the
    # specimens), it brings no light.
    blocked |= setup.misses_panel(origin, d, mi.Vector3f(ray.d)) | (dr.dot(d, mi.Vector3f(ray.d)) <= 0)
    return RefractedPath(total[0], stress[0], fringe, blocked, length, origin, d, interfaces, rotation, reflections,
                         tuple(zip(total, stress)))


@dr.syntax
def replay(scene: mi.Scene, ray: mi.Ray3f, setup: SceneSetup, method, step_size: float, seeds: mi.UInt32,
           active: mi.Bool, max_crossings: int, total: list[jones.Biquaternion],
           grad: list[jones.Biquaternion], bounces: int = 0) -> None:
    """The adjoint of :func:`trace`: back-propagate ``grad`` (the adjoint of the path's Jones matrix ``total``;
    both per wavelength of a spectral march) into every segment's field lookups.

    The path's matrix is ``M = L Q R``: ``L`` the part on the camera side of a
    segment (grown as the replay walks), ``Q`` the segment's own product (marched
    again, primal) and ``R = (L Q)^-1 M``. The segment's product receives the
    adjoint of ``q`` in ``L q R`` and replays its steps as in a straight walk.
    The interfaces are fixed (known geometry and indices): only the stress is
    differentiated. A sampled path (``bounces``) is walked again with the same
    choices (the same seeds, crossings and reflections taken).
    """
    d, u, v = _start(ray, setup)
    origin = mi.Point3f(ray.o)
    launch = mi.Point3f(ray.o)
    reach = mi.Float(ray.maxt)
    medium = mi.UInt32(0)
    before = (jones.from_quaternion(su2.identity(mi.Float(0))),) * len(total)
    crossings = mi.UInt32(0)
    reflections = mi.UInt32(0)
    active = mi.Bool(active)

    while dr.hint(active, exclude=[method, ray, scene, seeds, setup, total, grad]):
        si = _query(scene, launch, d, reach, ray, active)
        active &= ~(si.is_valid() & (crossings >= max_crossings))
        crossing = _crossing(si, origin, d, u, v, medium, setup, step_size, active,
                             reflection_choice(seeds, crossings, reflections, bounces))
        segment = Segment(crossing.steps, crossing.h, medium, origin, d, setup.frame_coefficients(u, v),
                               mi.sample_tea_32(seeds, crossings)[0])
        product, _ = method.march(segment, setup)
        with_segment, adjoint = _segment_adjoints(before, product, total, grad)
        method.replay(method.replay_start(product), adjoint, segment, setup)
        before = tuple(jones.multiply(m, crossing.matrix) for m in with_segment)
        reflections += dr.select(crossing.partial, 1, 0)
        d, u, v, medium, origin, launch, reach, hit = _advance(si, crossing, origin, launch, reach, active)
        crossings += 1
        active &= hit & ~crossing.blocked


def _segment_adjoints(before: tuple, product: tuple, total: list, grad: list) -> tuple[tuple, tuple]:
    """Per wavelength, the path's matrix up to the end of a segment whose product is ``product`` (a chain's state:
    one quaternion per wavelength) and the adjoint of that product in ``before q after = total``, side by side as
    the method's replay takes it."""
    with_segment = tuple(jones.multiply(b, jones.from_quaternion(q)) for b, q in zip(before, split_lanes(product)))
    adjoints = [jones.unitary_adjoint(b, jones.multiply(jones.inverse(w), t), g)
                for b, w, t, g in zip(before, with_segment, total, grad)]
    return with_segment, tuple(x for adjoint in adjoints for x in adjoint)


def _joined(total: tuple, stress: tuple, finished: tuple, matrix: jones.Biquaternion,
            where: mi.Bool | bool = True) -> tuple[tuple, tuple]:
    """Each wavelength's path matrix and stress product (``total``, ``stress``) with the segment marched since the
    last interface (``finished``: the method's finished state) and then ``matrix`` joined, where ``where`` holds."""
    segments = [_where(where, q, su2.identity(mi.Float(0))) for q in split_lanes(finished)]
    return (tuple(jones.multiply(jones.multiply(m, jones.from_quaternion(q)), matrix) for m, q in zip(total, segments)),
            tuple(su2.multiply(s, q) for s, q in zip(stress, segments)))


def _where(condition: mi.Bool, chosen: tuple, other: tuple) -> tuple:
    return tuple(dr.select(condition, a, b) for a, b in zip(chosen, other))


def _where_biquaternion(condition: mi.Bool, chosen: jones.Biquaternion) -> jones.Biquaternion:
    """``chosen`` where ``condition`` holds, the identity elsewhere."""
    identity = jones.from_quaternion(su2.identity(mi.Float(0)))
    return jones.Biquaternion((_where(condition, chosen[0], identity[0]), _where(condition, chosen[1], identity[1])))
