from __future__ import annotations

import contextlib
import logging
import math

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_nest import occupancy
from mi_nest.physics import MEASUREMENTS, Polariscope, aliasing, projection, su2
from mi_nest.physics import steps as steps_analysis

# Models of the ordered exponential along a ray (docs/physics.md section 4).
METHODS = ("product", "linear", "magnus4", "rk4", "auto")
# Where ``product`` samples each step: its midpoint (second order) or its start (first order).
POINTS = {"midpoint": 0.5, "left": 0.0}
# Queries again, each from a little further on, for a crossing that a ray inside a specimen did not find (walk).
EXTRA_LOOKS = 2
# Most steps a ray may take across the specimens. Beyond it float32 rounding of the steps outweighs their
# error (the disk at 6e7 steps: 10% off in retardance; at 1e-9 mm the step count overflows to none) and a
# view takes minutes.
MAX_STEPS_PER_RAY = 10 ** 6

JONES_CHANNELS = ("jones.a", "jones.b", "jones.c", "jones.d")
CHARACTERISTIC_CHANNELS = ("char.delta", "char.theta", "char.gamma")
# Unwrapped fringe order of the linear model, |sum of the step generators| / pi: exact
# where the axes do not turn along the ray, and what the aliasing guard differentiates.
FRINGE_CHANNELS = ("fringe.order",)
# Total length (mm) of each ray's path inside specimens: a thickness map.
PATH_CHANNELS = ("path.length",)
CHANNELS = JONES_CHANNELS + CHARACTERISTIC_CHANNELS + tuple(MEASUREMENTS) + FRINGE_CHANNELS + PATH_CHANNELS


class SceneSetupError(ValueError):
    """The scene cannot be rendered photoelastically (no specimen, no polariscope...)."""


class PhotoelasticIntegrator(mi.ad.integrators.common.ADIntegrator):
    r"""
    .. _integrator-photoelastic:

    Photoelastic integrator (:monosp:`photoelastic`)
    ------------------------------------------------

    .. pluginparameters::

     * - step_size
       - |float|
       - Longest march step in mm. Each chord through a specimen is split into
         ``ceil(L / step_size)`` equal steps. (Default: 0.5)

     * - jitter
       - |bool|
       - Sample each step at a uniformly random (stratified) point instead of
         its midpoint. (Default: |false|)

     * - method
       - |string|
       - Model of the ordered exponential (docs/physics.md section 4): ``product``
         (exact exponential per step), ``linear`` (sum the projected stress
         along the ray, exponentiate once: exact only when the steps commute),
         ``magnus4`` (two Gauss points per step plus the commutator; fourth
         order, unitary) or ``rk4`` (Runge-Kutta on the ODE; fourth order, not
         unitary) or ``auto`` (see ``tolerance``). (Default: ``product``)

     * - tolerance
       - |float|
       - For ``auto``: the largest error of the 16 normalised intensities to aim
         for. ``auto`` samples the field inside the specimens along the light
         before each render: where the principal axes never turn along the rays
         the steps commute and it uses ``linear`` (one step per chord for a field
         constant along the rays); otherwise ``magnus4`` with the longest step
         that step doubling on the hardest sampled chords finds within
         ``tolerance``. It logs its choice and why. (Default: 1e-3)

     * - points
       - |string|
       - For ``product``: sample each step at its ``midpoint`` (second order)
         or at its ``left`` end (first order). (Default: ``midpoint``)

     * - max_crossings
       - |int|
       - Most surface crossings followed per ray; a guard against broken meshes.
         (Default: 64)

    Renders integrated photoelasticity (docs/physics.md): for every camera ray it
    follows the light from the ``polariscope_light`` panel to the camera through
    every shape whose interior is a ``stress`` medium, entering and leaving as
    often as the geometry requires (entry where the ray meets the outside of a
    surface, exit at the next crossing; specimens may touch face to face, but
    not nest), and multiplies the exact exponential
    of each constant-stress step as an SU(2) quaternion, renormalised at every
    step. Any other shape is opaque.

    The film receives the intensity of the scene's polariscope as its main
    channel (``Y``) and, as named channels, the Jones product
    ``jones.a/b/c/d``, its characteristic parameters ``char.delta``,
    ``char.theta``, ``char.gamma`` (radians), the 16 normalised intensities
    ``pol.<b1>.<b2>.<a2>`` of the multi-axis polariscope, ``fringe.order`` (the
    linear model's unwrapped fringe order: exact where the axes do not turn
    along the ray) and ``path.length``, the length (mm) of the ray's path
    inside specimens. After each render it measures the fringe density from
    ``fringe.order`` and warns where fringes are denser than the pixel grid
    (``integrator.aliasing`` keeps the report).

    .. tabs::

        .. code-tab:: xml

            <integrator type="photoelastic">
                <float name="step_size" value="0.25"/>
            </integrator>
    """

    def __init__(self, props):
        mi.CppADIntegrator.__init__(self, props)
        self.step_size = float(props.get("step_size", 0.5))
        if not (math.isfinite(self.step_size) and self.step_size > 0):
            raise ValueError(f"photoelastic: 'step_size' must be a positive length in mm, "
                             f"got {self.step_size}")
        self.jitter = bool(props.get("jitter", False))
        self.method = props.get("method", "product")
        if self.method not in METHODS:
            raise ValueError(f"photoelastic: unknown method '{self.method}'; choose one of {METHODS}")
        self.points = props.get("points", "midpoint")
        if self.points not in POINTS:
            raise ValueError(f"photoelastic: unknown points '{self.points}'; choose one of {tuple(POINTS)}")
        if self.method != "product" and "points" in props:
            raise ValueError("photoelastic: 'points' applies to method 'product' only")
        self.tolerance = float(props.get("tolerance", 1e-3))
        if not (math.isfinite(self.tolerance) and self.tolerance > 0):
            raise ValueError(f"photoelastic: 'tolerance' must be positive, got {self.tolerance}")
        self.auto_choice = None
        self._decided = None        # (method, step) that 'auto' keeps inside deciding_once()
        self.aliasing = None
        self.max_crossings = int(props.get("max_crossings", 64))
        if self.max_crossings < 2:
            raise ValueError(f"photoelastic: 'max_crossings' must be at least 2, got {self.max_crossings}")
        self._setup = None
        self._norm_error = None
        self._method, self._step = self.method, self.step_size

    def aov_names(self):
        return list(CHANNELS)

    def to_string(self):
        return (f"PhotoelasticIntegrator[method={self.method}, step_size={self.step_size:g} mm, "
                f"points={self.points}, jitter={self.jitter}, max_crossings={self.max_crossings}]")

    def channel_names(self, film):
        """Names of the channels of the image :meth:`render` returns, in order."""
        if _sums_pixels_directly(film) and _develops_directly(film):
            return _developed_names(film)
        return [str(f.name) for f in film.bitmap().struct_()]

    def check_scene(self, scene, sensor=0):
        """Raise :class:`SceneSetupError` naming what the scene lacks.

        ``mi.render`` reports exceptions raised inside ``render`` only as a failed
        custom operation, so callers that want the message check first.
        """
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        with self._prepared(scene, sensor) as setup:    # what render prepares, the step count included
            return setup

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        with self._prepared(scene, sensor):
            if not _sums_pixels_directly(sensor.film()):
                image = super().render(scene, sensor, seed, spp, develop, evaluate)
                guarded = _guarded_channels(image) if develop and isinstance(image, mi.TensorXf) else None
            elif not develop:
                raise ValueError("photoelastic: develop=True must be specified")
            else:
                image, guarded = self._render_pixel_sums(scene, sensor, seed, spp)
            if self._norm_error is not None:
                _warn_if_not_unitary(float(self._norm_error[0]), self._step)
            if guarded is not None:
                self.aliasing = _check_aliasing(*guarded)
            return image

    def render_backward(self, scene, params, grad_in, sensor=0, seed=0, spp=0):
        """Reverse-mode derivative of :meth:`render` by path replay: memory does not grow with the steps.

        ``grad_in`` is the adjoint of the developed image; every channel but
        ``fringe.order`` and ``path.length`` propagates to the field.
        """
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        film = sensor.film()
        if not _sums_pixels_directly(film):
            raise ValueError("photoelastic: differentiable rendering needs a box-filtered film "
                             '(<rfilter type="box"/>) without border')
        with self._prepared(scene, sensor), dr.suspend_grad():
            self._require_adjoint()
            sampler, spp = self.prepare(sensor, seed, spp, self.aov_names())
            ray, weight, _ = self.sample_rays(scene, sensor, sampler)
            # Each pixel is the mean of its spp consecutive samples: each sample receives grad / spp.
            grad = mi.TensorXf(grad_in)
            channels = grad.shape[-1]
            pixel = dr.arange(mi.UInt32, dr.width(ray.o)) // spp
            per_sample = [dr.gather(mi.Float, grad.array, pixel * channels + c) * (weight / spp)
                          for c in range(channels)]
            first = channels - len(CHANNELS)
            _, _, _, state = self.sample(dr.ADMode.Primal, scene, sampler.clone(), ray, mi.Bool(True))
            self.sample(dr.ADMode.Backward, scene, sampler, ray, mi.Bool(True), δL=mi.Spectrum(per_sample[0]),
                        δaovs=per_sample[first:], state_in=state)

    def render_forward(self, scene, params, sensor=0, seed=0, spp=0):
        raise NotImplementedError("photoelastic: forward-mode derivatives are not available; differentiate in "
                                  "reverse mode (dr.backward on the rendered image)")

    @contextlib.contextmanager
    def _prepared(self, scene, sensor, right=None):
        """Scene lookup tables and the method for one render (``auto`` decides here)."""
        if sensor is None and self.method == "auto":
            raise ValueError("photoelastic: 'auto' analyses the field as one camera sees it; rays drawn across "
                             "views need an explicit method and step_size")
        self._setup = _SceneSetup(scene, sensor, right)
        self._method, self._step = self.method, self.step_size
        try:
            if self.method == "auto" and self._decided is not None:
                self._method, self._step = self._decided
            elif self.method == "auto":
                self._method, self._step, self.auto_choice = _choose_method(self._setup, scene, sensor,
                                                                            self.tolerance)
                logging.getLogger("mi_nest").info(self.auto_choice)
            _check_steps_per_ray(self._setup.specimen_diagonal, self._step)
            yield self._setup
        finally:
            self._setup = None
            self._norm_error = None

    @contextlib.contextmanager
    def deciding_once(self, scene, sensor=0):
        """Renders inside the block reuse one ``auto`` analysis, made on entry.

        For several passes over one unchanged scene and camera (``mi_nest.render``
        splits its samples so): the analysis costs about 10 ms whatever the
        resolution. The scene must not change inside the block.
        """
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if self.method != "auto" or self._decided is not None:
            yield
            return
        with self._prepared(scene, sensor):
            self._decided = (self._method, self._step)
        try:
            yield
        finally:
            self._decided = None

    def _require_adjoint(self):
        if self._method == "rk4":
            raise ValueError("photoelastic: rk4 is not unitary, so its march cannot be replayed backwards; "
                             "differentiate with 'product', 'magnus4' or 'linear'")

    def trace_rays(self, scene, rays, right, seed=0):
        """Primal march of arbitrary rays (e.g. a training batch drawn across views).

        ``right`` is each ray's image-right direction (its camera's), which fixes
        the polariscope frame. Returns ``(state, blocked, length)``: the
        accumulated state (the Jones quaternion, or for ``linear`` the summed
        generator; see :meth:`jones`), whether an opaque shape stops the ray, and
        its path length (mm) inside specimens.
        """
        with dr.suspend_grad(), self._prepared(scene, None, right) as setup:
            seeds = _ray_seeds(seed, dr.width(rays.o))
            (state, _), blocked, length = self.walk(scene, rays, setup, mi.Bool(True), seeds,
                                                    self._primal_carry(), self._primal_segment)
            dr.eval(state, blocked, length)
            return state, blocked, length

    def backpropagate_rays(self, scene, rays, right, state, state_grad, seed=0):
        """Accumulate into the field parameters the gradient of ``sum(state_grad . state)``.

        Replays the march of :meth:`trace_rays` (same rays, right and seed);
        Jones steps are unitary, so the part of the product still ahead is
        peeled off with conjugates instead of being stored: memory does not
        grow with the number of steps.
        """
        with dr.suspend_grad(), self._prepared(scene, None, right) as setup:
            self._require_adjoint()
            # Unevaluated adjoints carry the loss's constants (1 / batch size...) into the kernel,
            # which would then be rebuilt whenever they change.
            state, state_grad = tuple(mi.Float(x) for x in state), tuple(mi.Float(x) for x in state_grad)
            dr.make_opaque(state, state_grad)
            seeds = _ray_seeds(seed, dr.width(rays.o))
            self.replay(scene, rays, setup, mi.Bool(True), seeds, state, state_grad)

    def jones(self, state, blocked):
        """The Jones quaternion from a traced state (zero where blocked)."""
        return tuple(dr.select(blocked, 0.0, x) for x in self.finish(state))

    def _render_pixel_sums(self, scene, sensor, seed, spp):
        """``ADIntegrator.render`` for box-filtered films, without per-sample atomics.

        Returns the developed image and, for the aliasing guard, its fringe order
        and path length as contiguous ``(H, W)`` host arrays: read from the
        interleaved image, every value would cost a cache line.
        """
        film = sensor.film()
        with dr.suspend_grad():
            sampler, spp = self.prepare(sensor, seed, spp, self.aov_names())
            ray, weight, _ = self.sample_rays(scene, sensor, sampler)
            main, _, aovs, _ = self.sample(dr.ADMode.Primal, scene, sampler, ray, mi.Bool(True))
            value = (main * weight)[0]
            # The channel layout of ADIntegrator._splat_to_block: colour, alpha, weight, AOVs.
            one = dr.full(mi.Float, 1.0, dr.width(value))
            alpha = mi.has_flag(film.flags(), mi.FilmFlags.Alpha)
            channels = [value, value, value] + ([one] if alpha else [])
            channels += [one] + aovs
            sums = _pixel_sums(spp, channels)
            guarded = [sums[i] for i in _guarded_positions(len(sums))]
            width, height = film.crop_size()
            if _develops_directly(film):
                # What film.develop() would return, written by the march's own kernel: the film's put,
                # conversion and normalisation passes over the image cost 7% of a 256-step 256^2 render.
                developed = sums[:1] + sums[3:4 if alpha else 3] + sums[len(sums) - len(CHANNELS):]
                image = _interleave([x / spp for x in developed], height, width)
                dr.eval(image, guarded)
                film.put_block(mi.ImageBlock(tensor=_film_sums(image, spp, alpha), offset=film.crop_offset(),
                                             rfilter=film.rfilter()))
            else:
                block = _interleave(sums, height, width)
                dr.eval(block, guarded)     # in the kernel that interleaves the channels
                film.put_block(mi.ImageBlock(tensor=block, offset=film.crop_offset(), rfilter=film.rfilter()))
                image = film.develop()
            return image, tuple(x.numpy().reshape(height, width) / spp for x in guarded)

    def sample(self, mode, scene, sampler, ray, active, δL=None, δaovs=None, state_in=None, **kwargs):
        setup = self._setup
        seeds = mi.UInt32(sampler.next_1d() * 4294967296.0)
        if mode == dr.ADMode.Primal:
            (state, fringe), blocked, length = self.walk(scene, ray, setup, active, seeds,
                                                         self._primal_carry(), self._primal_segment)
            if self._method == "rk4":
                # The only method that is not unitary: measure how far it drifted (read after the render).
                self._norm_error = dr.max(dr.select(blocked, 0.0, dr.abs(su2.norm_squared(state) - 1.0)))
            main, aovs = self.outputs(state, fringe, blocked, length)
            return main, mi.Bool(True), aovs, (state, fringe, blocked, length)
        if mode != dr.ADMode.Backward:
            raise NotImplementedError("photoelastic: forward-mode derivatives are not available")
        state, fringe, blocked, length = state_in
        with dr.resume_grad():
            leaf = tuple(mi.Float(dr.detach(x)) for x in state)
            dr.enable_grad(leaf)
            main, aovs = self.outputs(leaf, fringe, blocked, length)
            objective = dr.sum(δL * main)
            for name, value, grad in zip(CHANNELS, aovs, δaovs):
                # Only channels of the Jones product carry a derivative; skipping zero adjoints also
                # keeps 0 * inf (char.theta at zero retardance) out of the sum.
                if name not in UNDIFFERENTIATED and dr.any(grad != 0, axis=None):
                    objective += grad * value
            dr.backward_from(objective)
            state_grad = dr.grad(leaf)
        self.replay(scene, ray, setup, active, seeds, state, state_grad)
        return mi.Spectrum(0), mi.Bool(True), [mi.Float(0)] * len(CHANNELS), None

    def outputs(self, state, fringe, blocked, length):
        """Main intensity and the AOV channels from a traced state."""
        setup = self._setup
        q = self.jones(state, blocked)
        delta, theta, gamma = su2.characteristic_parameters(q)
        radiance = setup.radiance
        aovs = list(q) + [delta, theta, gamma]
        aovs += [radiance * scope.intensity(q) for scope in MEASUREMENTS.values()]
        aovs.append(dr.select(blocked, 0.0, dr.norm(mi.Vector2f(fringe)) / dr.pi))
        aovs.append(length)
        return mi.Spectrum(radiance * setup.polariscope.intensity(q)), aovs

    @dr.syntax
    def walk(self, scene, ray, setup, active, seeds, carry, segment):
        """Follow each ray through every specimen; ``carry = segment(carry, ...)`` for each inside segment.

        Returns ``(carry, blocked, length)``: whether an opaque shape stops the ray,
        and its length inside specimens. The primal pass and the adjoint replay
        differ only in ``carry`` and ``segment``.

        Inside a specimen the next crossing must be its exit (or a glued
        neighbour's face, or an opaque shape), and an exit must follow an entry
        (or another specimen's exit: faces glued, the coincident entry skipped).
        Where they do not, Embree missed a face where the ray met a mesh edge (it
        does without robust intersections, whatever flags the scene was loaded
        with) or the ray grazed a silhouette: the query is made again from a
        point nudged by a surface clearance (``occupancy.nudged``), not flagged
        coherent (coherent queries round alike), up to :data:`EXTRA_LOOKS`
        times. What is still there was a touch, and marches nothing.
        """
        d = mi.Vector3f(ray.d)
        coefficients = setup.projection_coefficients(d)
        origin = mi.Point3f(ray.o)
        launch = mi.Point3f(ray.o)      # where the next intersection query starts
        reach = mi.Float(ray.maxt)      # and how far it looks: the camera's range, then unbounded
        medium = mi.UInt32(0)           # 0 outside, i + 1 inside specimen medium i
        current = mi.UInt32(0)          # the specimen shape the ray is in (0 outside)
        after_exit = mi.Bool(False)     # whether the last crossing left a specimen
        looks = mi.UInt32(0)            # queries again for the same crossing
        blocked = mi.Bool(False)
        length = mi.Float(0)
        crossings = mi.UInt32(0)
        active = mi.Bool(active)

        # Only what changes is loop state: Dr.Jit traces the body again to drop any state that does not.
        while dr.hint(active, exclude=[coefficients, d, ray, scene, seeds, segment, self, setup]):
            si = scene.ray_intersect(mi.Ray3f(launch, d, reach, ray.time, ray.wavelengths),
                                     ray_flags=mi.RayFlags.Minimal, coherent=setup.coherent_rays & (looks == 0),
                                     active=active)
            hit = si.is_valid()
            shape = dr.reinterpret_array(mi.UInt32, si.shape)
            hit_medium = dr.gather(mi.UInt32, setup.medium_of_shape, shape, hit)
            entering = dr.dot(si.n, d) < 0
            exiting = hit & ~entering & (hit_medium != 0)
            unexpected = dr.select(medium != 0, ~hit | (entering & (shape == current)), exiting & ~after_exit)
            look_again = active & unexpected & (looks < EXTRA_LOOKS)
            # Leaving a specimen proves the segment was inside it, even if its entry face was
            # skipped for coinciding with the face just left (specimens glued face to face).
            inside = dr.select(exiting, hit_medium, medium)
            # The chord between hit points, not the spawned ray's t (its origin is offset).
            chord = dr.norm(si.p - origin)
            marched = active & hit & (inside != 0) & ~unexpected
            steps = mi.UInt32(dr.select(marched, dr.maximum(dr.ceil(chord / self._step), 1), 0))
            h = chord / mi.Float(dr.maximum(steps, 1))
            segment_seed = mi.sample_tea_32(seeds, crossings)[0]
            carry = segment(carry, _Segment(steps, h, inside, origin, d, coefficients, segment_seed), setup)
            length += dr.select(marched, chord, 0.0)
            crossed = ~look_again
            blocked |= crossed & hit & (hit_medium == 0)
            medium = dr.select(crossed, dr.select(entering, hit_medium, 0), medium)
            current = dr.select(crossed, dr.select(entering & (hit_medium != 0), shape, 0), current)
            after_exit = dr.select(crossed, exiting & ~unexpected, after_exit)
            origin = dr.select(crossed, si.p, origin)
            launch = dr.select(crossed, occupancy.past_surface(si, d), occupancy.nudged(launch, d, looks))
            reach = dr.select(crossed, dr.inf, reach)
            looks = dr.select(crossed, 0, looks + 1)
            crossings += 1
            active &= (hit | look_again) & ~blocked & (crossings < self.max_crossings)
        return carry, blocked, length

    def _primal_carry(self):
        return self.accumulate_start(), (mi.Float(0), mi.Float(0))

    def _primal_segment(self, carry, segment, setup):
        q, fringe = carry
        result, segment_fringe = self.march(segment, setup)
        return self.accumulate(q, result), _add(fringe, segment_fringe)

    def replay(self, scene, ray, setup, active, seeds, state, state_grad):
        """Adjoint pass: march again, back-propagating ``state_grad`` into every step's field lookups.

        ``linear``: the state is a sum, so each step receives ``state_grad`` itself.
        Products ``J = A U B``: a step ``U`` receives ``conj(A) dJ conj(B)``, where
        ``A`` (the steps before) grows and ``B = conj(U) B`` (the steps after) shrinks
        as the replay advances: both are exact since every step is unitary.
        """
        if self._method == "linear":
            def segment(carry, segment, setup):
                self.replay_linear(state_grad, segment, setup)
                return carry
            carry = mi.Float(0)
        else:
            def segment(carry, segment, setup):
                return self.replay_chain(carry, state_grad, segment, setup)
            carry = (su2.identity(mi.Float(0)), tuple(mi.Float(x) for x in state))
        self.walk(scene, ray, setup, active, seeds, carry, segment)

    @dr.syntax
    def replay_chain(self, carry, state_grad, segment, setup):
        before, after = carry
        i = mi.UInt32(0)
        while dr.hint(i < segment.steps, exclude=[segment, self, setup, state_grad]):
            with dr.resume_grad():
                propagator, _ = self.step(i, segment, setup)
                unit = dr.detach(propagator)
                after = su2.renormalize(su2.multiply(su2.conjugate(unit), after))
                adjoint = su2.multiply(su2.multiply(su2.conjugate(before), state_grad), su2.conjugate(after))
                dr.backward_from(_dot(adjoint, propagator))
            before = su2.multiply_renormalized(before, unit)
            i += 1
        return before, after

    @dr.syntax
    def replay_linear(self, state_grad, segment, setup):
        i = mi.UInt32(0)
        while dr.hint(i < segment.steps, exclude=[segment, self, setup, state_grad]):
            with dr.resume_grad():
                generator = self.generator_at(segment.point(i, self._offset(segment, i)), segment, setup)
                dr.backward_from(segment.h * _dot(state_grad, generator))
            i += 1

    def accumulate_start(self):
        zero = mi.Float(0)
        return (zero, zero, zero, zero) if self._method == "linear" else su2.identity(zero)

    def accumulate(self, q, segment):
        """Combine a segment's result with the ray's so far: a product, or for ``linear`` a sum."""
        if dr.hint(self._method == "linear", mode="scalar"):
            return tuple(x + y for x, y in zip(q, segment))
        return su2.multiply(q, segment)

    def finish(self, q):
        """The Jones quaternion from the accumulated state (``linear``: one exponential of the sum)."""
        if dr.hint(self._method == "linear", mode="scalar"):
            return su2.exponential(q)
        return q

    def march(self, segment, setup):
        """The segment's propagator (``linear``: its summed generator) and ``(b, c)`` of its summed generator."""
        if self._method == "rk4":
            return self.march_rk4(segment, setup)
        if self._method == "linear":
            return self.march_linear(segment, setup)
        return self.march_chains(segment, setup)

    @dr.syntax
    def march_chains(self, segment, setup):
        """Ordered product of per-step propagators (``product``, ``magnus4``).

        Marching away from the camera goes against the light, so later steps
        multiply on the right. The chord's front and back halves are two
        independent products advanced in the same iteration (then joined, which
        is exact): two dependency chains keep the vector units busy where a
        single chain would leave them waiting on its latency. An odd count
        leaves the back half one index past the end: a zero-length step.
        """
        half = (segment.steps + 1) // 2
        front = su2.identity(mi.Float(0))
        back = su2.identity(mi.Float(0))
        fringe = (mi.Float(0), mi.Float(0))
        i = mi.UInt32(0)
        while dr.hint(i < half, exclude=[half, segment, self, setup]):
            front_step, front_fringe = self.step(i, segment, setup)
            back_step, back_fringe = self.step(i + half, segment, setup)
            front = su2.multiply_renormalized(front, front_step)
            back = su2.multiply_renormalized(back, back_step)
            fringe = _add(fringe, _add(front_fringe, back_fringe))
            i += 1
        return su2.multiply(front, back), fringe

    def _offset(self, segment, index):
        """Where in step ``index`` the field is sampled, as a fraction of the step.

        Jittered offsets hash (segment, index) instead of drawing from a sampler,
        so the adjoint replay, which visits the steps in another order, samples
        the same points.
        """
        if self.jitter:
            return mi.sample_tea_float32(segment.seed, index)
        return mi.Float(POINTS[self.points])

    def step(self, index, segment, setup):
        """Propagator of step ``index`` (zero length past the segment's steps) and the
        ``(b, c)`` part of its mean generator times its length."""
        length = dr.select(index < segment.steps, segment.h, 0.0)
        if self._method == "magnus4":
            # Gauss points in light order: the farther one from the camera first.
            first, second = (self.generator_at(segment.point(index, g), segment, setup)
                             for g in steps_analysis.GAUSS_POINTS)
            half = 0.5 * length
            return su2.magnus4(first, second, length), (half * (first[1] + second[1]),
                                                        half * (first[2] + second[2]))
        point = segment.point(index, self._offset(segment, index))
        generator = su2.generator(*self.transverse(point, segment, setup), length)
        return su2.exponential(generator), generator[1:3]

    def transverse(self, p, segment, setup):
        """``(s_uu - s_vv, 2 s_uv)`` at ``p``, scaled to phase per mm."""
        return projection.apply_coefficients(segment.coefficients, setup.phase_tensor(segment.medium, p))

    def generator_at(self, p, segment, setup):
        """The propagation generator per unit length at ``p`` (a pure quaternion)."""
        return su2.generator(*self.transverse(p, segment, setup))

    @dr.syntax
    def march_linear(self, segment, setup):
        """Midpoint (or jittered) sum of the generator over the segment (``linear``: exponentiated once per ray)."""
        total = (mi.Float(0), mi.Float(0), mi.Float(0), mi.Float(0))
        i = mi.UInt32(0)
        while dr.hint(i < segment.steps, exclude=[segment, self, setup]):
            total = _axpy(segment.h, self.generator_at(segment.point(i, self._offset(segment, i)), segment, setup),
                          total)
            i += 1
        return total, total[1:3]

    @dr.syntax
    def march_rk4(self, segment, setup):
        """Classical Runge-Kutta on ``K' = K A(t)`` (t from the camera): fourth order, not unitary.

        Its amplification per step is ``|R(i x)|^2 = 1 - x^6/72 + x^8/576`` for a
        phase ``x`` per step: it damps below ``x = 2 sqrt(2)`` and blows up above.
        """
        h = segment.h
        k = su2.identity(mi.Float(0))
        fringe = (mi.Float(0), mi.Float(0))
        i = mi.UInt32(0)
        while dr.hint(i < segment.steps, exclude=[h, segment, self, setup]):
            a0, am, a1 = (self.generator_at(segment.point(i, f), segment, setup) for f in (0.0, 0.5, 1.0))
            k1 = su2.multiply(k, a0)
            k2 = su2.multiply(_axpy(0.5 * h, k1, k), am)
            k3 = su2.multiply(_axpy(0.5 * h, k2, k), am)
            k4 = su2.multiply(_axpy(h, k3, k), a1)
            k = _axpy(h / 6.0, _rk4_slope(k1, k2, k3, k4), k)
            fringe = _axpy(h, am[1:3], fringe)
            i += 1
        return k, fringe


class _Segment:
    """One inside chord of each ray: ``steps`` steps of length ``h`` from ``origin`` along ``d``."""

    DRJIT_STRUCT = {"steps": mi.UInt32, "h": mi.Float, "medium": mi.UInt32, "origin": mi.Point3f,
                    "d": mi.Vector3f, "coefficients": tuple, "seed": mi.UInt32}

    def __init__(self, steps=None, h=None, medium=None, origin=None, d=None, coefficients=None, seed=None):
        self.steps, self.h, self.medium, self.origin, self.d = steps, h, medium, origin, d
        self.coefficients, self.seed = coefficients, seed

    def point(self, index, offset):
        """The point a fraction ``offset`` into step ``index``."""
        return dr.fma(self.d, (mi.Float(index) + offset) * self.h, self.origin)


def _ray_seeds(seed, count):
    # Opaque: a literal seed would be compiled into the kernel, rebuilding it for every new seed.
    return mi.sample_tea_32(dr.opaque(mi.UInt32, seed), dr.arange(mi.UInt32, count))[0]


def _dot(x, y):
    return sum(a * b for a, b in zip(x, y))


# Channels whose derivative ``render_backward`` does not propagate: the fringe-order estimate
# and the path length are diagnostics, not functions of the Jones product.
UNDIFFERENTIATED = FRINGE_CHANNELS + PATH_CHANNELS


# |J|^2 may drift this far from 1 before rk4 results are reported as unreliable.
RK4_NORM_TOLERANCE = 1e-3


def _warn_if_not_unitary(norm_error, step_size):
    if norm_error > RK4_NORM_TOLERANCE:
        import warnings
        warnings.warn(
            f"photoelastic: rk4 is not unitary here: | |J|^2 - 1 | reaches {norm_error:.3g} (step_size "
            f"{step_size:g} mm). RK4 shrinks |J|^2 by about x^6/72 per step and blows up when the phase x "
            f"per step exceeds 2 sqrt(2) = 2.83 rad; use a smaller step_size, or 'product'/'magnus4'",
            RuntimeWarning, stacklevel=2)


def _guarded_positions(count):
    """Where the aliasing guard's channels (fringe order, path length) sit among ``count`` channels
    that end with the AOVs."""
    return [count - len(CHANNELS) + CHANNELS.index(name) for name in FRINGE_CHANNELS + PATH_CHANNELS]


def _guarded_channels(image):
    """The fringe order and path length of a developed image, as ``(H, W)`` host arrays."""
    pixels = image.numpy()      # shares the evaluated image's memory on the LLVM backend
    return tuple(pixels[..., i] for i in _guarded_positions(image.shape[-1]))


def _check_aliasing(order, length):
    """Measure the fringe density of an image's order channel; warn if the intensities alias."""
    report = aliasing.fringe_aliasing(order, length > 0)
    if report.aliases:
        import warnings
        warnings.warn(f"photoelastic: {report.describe()}: the intensities alias there. Render at "
                      f"{report.resolution_factor}x the resolution, or supersample (spp) to average the "
                      "fringes within each pixel as a camera does", RuntimeWarning, stacklevel=3)
    return report


# Lines across each specimen and samples along each line for the ``auto`` analysis.
_AUTO_LINES, _AUTO_SAMPLES = 32, 65
# Of those lines, how many are marched at halving steps to estimate the magnus4 error.
_AUTO_CHORDS = 64
# The step when no analysis line meets a specimen.
_AUTO_FALLBACK_STEP = 1.0


def _choose_method(setup, scene, sensor, tolerance):
    """``(method, step_size, reason)`` for ``auto``, from the fields sampled along the light."""
    to_world = sensor.world_transform()
    k = -np.array(dr.normalize(to_world @ mi.Vector3f(0, 0, 1))).ravel()    # light travels towards the camera
    u = np.array(setup._right).ravel()
    u = u - (u @ k) * k
    u /= np.linalg.norm(u)
    v = np.cross(k, u)
    rates, lines = [], []
    for shape in scene.shapes():
        medium = shape.interior_medium()
        if medium is None or not hasattr(medium, "phase_tensor"):
            continue
        box = shape.bbox()
        corners = np.array([[x, y, z] for x in (box.min.x, box.max.x) for y in (box.min.y, box.max.y)
                            for z in (box.min.z, box.max.z)], dtype=np.float64)
        span = [(corners @ axis).min() for axis in (u, v, k)], [(corners @ axis).max() for axis in (u, v, k)]
        a, b = (np.linspace(lo, hi, _AUTO_LINES + 2)[1:-1] for lo, hi in zip(span[0][:2], span[1][:2]))
        s = np.linspace(span[0][2], span[1][2], _AUTO_SAMPLES)
        grid_a, grid_b, grid_s = np.meshgrid(a, b, s, indexing="ij")
        points = grid_a[..., None] * u + grid_b[..., None] * v + grid_s[..., None] * k
        starts = points[:, :, 0].reshape(-1, 3)
        crossings = occupancy.crossings_along_lines(scene, shape, starts, k)
        inside = (crossings[:, :, None] < (s - s[0])[None, None, :]).sum(axis=0) % 2 == 1
        if not inside.any():
            continue
        generator = _generator_sampler(medium, u, v)
        p, q = generator(points.reshape(inside.shape + (3,)))
        rates.append(steps_analysis.analyse_lines(p, q, s[1] - s[0], inside))
        lines.append((generator, p, q, inside, starts, crossings))
    if not rates:
        return "linear", _AUTO_FALLBACK_STEP, ("photoelastic auto: no analysis line crossed a specimen; "
                                               "linear model")
    commuting = all(r.commuting for r in rates)
    combined = steps_analysis.FieldRates(
        commuting, max(r.retardance_rate for r in rates), max(r.rotation_rate for r in rates),
        max(r.path_length for r in rates), max(r.curvature for r in rates))
    if commuting:
        step = steps_analysis.linear_step(combined, tolerance)
        return "linear", step, (
            f"photoelastic auto: the principal axes do not turn along the light in any specimen, so the steps "
            f"commute and the linear model is exact; step {step:.3g} mm for the summed stress "
            f"(retardance up to {combined.retardance_rate:.3g} rad/mm)")
    # Step doubling on the chords themselves: rates alone cannot tell a field that turns from one that
    # is merely strong (a constant generator is exact at any step) or jumps once at an interface.
    chords = []
    for generator, p, q, inside, starts, crossings in lines:
        hardest = steps_analysis.hardest_lines(p, q, inside, _AUTO_CHORDS)
        chords.append((generator, *_chords(starts[hardest], k, crossings[:, hardest])))
    step, error = min(steps_analysis.magnus4_step(generator, starts, -k, lengths, tolerance)
                      for generator, starts, lengths in chords)
    count = sum(len(lengths) for _, _, lengths in chords)
    return "magnus4", step, (
        f"photoelastic auto: the principal axes turn along the light (up to {combined.rotation_rate:.3g} rad/mm "
        f"between samples), so the linear model would be wrong; magnus4 with step {step:.3g} mm, where step "
        f"doubling on {count} chords estimates an error of {error:.2g} (tolerance {tolerance:g})")


def _generator_sampler(medium, u, v):
    """NumPy ``points -> (p, q)``: the step generator per mm of ``medium`` in the basis (u, v)."""
    coefficients = projection.projection_coefficients(tuple(map(float, u)), tuple(map(float, v)))

    def generator(points):
        # One kernel from points to (p, q): projected where the field is sampled, two arrays come back, not six.
        shape = points.shape[:-1]
        flat = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        p, q = projection.apply_coefficients(coefficients, medium.phase_tensor(mi.Point3f(flat.T)))
        dr.eval(p, q)
        return tuple(np.broadcast_to(np.array(x, dtype=np.float64), (len(flat),)).reshape(shape) for x in (p, q))
    return generator


def _chords(starts, k, crossings):
    """Inside segments of each line as ``(camera-side ends, lengths)``: crossings pair up in order."""
    ends, lengths = [], []
    for line, distances in enumerate(crossings.T):
        distances = np.sort(distances[np.isfinite(distances)])
        for enter, leave in zip(distances[0::2], distances[1::2]):
            ends.append(starts[line] + leave * k)
            lengths.append(leave - enter)
    return np.array(ends).reshape(-1, 3), np.array(lengths)


def _add(x, y):
    return tuple(xi + yi for xi, yi in zip(x, y))


def _axpy(a, x, y):
    return tuple(a * xi + yi for xi, yi in zip(x, y))


def _rk4_slope(k1, k2, k3, k4):
    return tuple(y1 + 2.0 * y2 + 2.0 * y3 + y4 for y1, y2, y3, y4 in zip(k1, k2, k3, k4))


# Shapes known to be closed, by registry id and face count (checking costs a pass over the faces).
_CLOSED_SHAPES = set()
# Mitsuba's analytic shapes that bound a volume (cylinder and disk are open surfaces).
_CLOSED_ANALYTIC_SHAPES = ("Sphere",)


def _require_closed(shape, shape_id):
    """A specimen must be a closed surface, or rays that enter it never leave."""
    name = shape.id() or shape.class_name()
    if not shape.is_mesh():
        if shape.class_name() not in _CLOSED_ANALYTIC_SHAPES:
            raise SceneSetupError(f"photoelastic: specimen '{name}' ({shape.class_name()}) is not a closed "
                                  "surface; use a closed mesh (or a sphere) to hold a stress medium")
        return
    key = (shape_id, shape.face_count())
    if key in _CLOSED_SHAPES:
        return
    # Weld by position: meshes repeat vertices along creases (Mitsuba's cube does), as exact copies.
    positions = np.array(shape.vertex_positions_buffer()).reshape(-1, 3)
    _, welded = np.unique(positions, axis=0, return_inverse=True)
    faces = welded.ravel()[np.array(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)]
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    open_edges = int(np.count_nonzero(uses != 2))
    if open_edges:
        raise SceneSetupError(f"photoelastic: specimen '{name}' is not a closed mesh ({open_edges} edges not "
                              "shared by exactly two faces); rays entering it would never leave")
    _CLOSED_SHAPES.add(key)


def _sums_pixels_directly(film):
    """A box-filtered film without border receives each sample in its own pixel only."""
    return film.rfilter().is_box_filter() and not film.sample_border() and \
        film.rfilter().border_size() == 0


def _develops_directly(film):
    """Whether the integrator writes ``film.develop()``'s image itself: a monochrome HDR film,
    whose image is luminance (and alpha) then the AOVs, each pixel's sum over its weight."""
    return film.class_name() == "HDRFilm" and mi.is_monochromatic


def _check_steps_per_ray(diagonal, step):
    steps = diagonal / step
    if steps > MAX_STEPS_PER_RAY:
        raise SceneSetupError(f"photoelastic: step_size {step:g} mm makes up to {steps:.3g} steps per ray across "
                              f"the specimens (their bounding box diagonal is {diagonal:.4g} mm); the most is "
                              f"{MAX_STEPS_PER_RAY:.0e}: use a step_size of at least "
                              f"{diagonal / MAX_STEPS_PER_RAY:.2g} mm")


def _developed_names(film):
    alpha = ["A"] if mi.has_flag(film.flags(), mi.FilmFlags.Alpha) else []
    return ["Y"] + alpha + list(CHANNELS)


def _pixel_sums(spp, channels):
    """Sum the ``spp`` consecutive samples of each pixel, channel by channel.

    ``ADIntegrator.sample_rays`` orders samples pixel by pixel, row-major, so a
    block reduction (then one interleaving pass) replaces an atomic add per
    sample and channel in ``ImageBlock.put``.
    """
    if spp == 1:
        return channels
    dr.eval(channels)   # one march for all channels, not one per reduction
    return [dr.block_sum(channel, spp) for channel in channels]


def _interleave(channels, height, width):
    """``(H, W, C)`` image from one flat array per channel."""
    return mi.TensorXf(dr.ravel(mi.ArrayXf(channels), order="F"), (height, width, len(channels)))


def _film_sums(image, spp, alpha):
    """The film's block (colour, alpha, weight, AOVs: pixel sums) rebuilt from a developed image.

    Lazy: it costs nothing unless something reads the film (``film.bitmap()``,
    ``film.write()``), and then only a gather from the evaluated image, not a new march.
    """
    height, width, count = image.shape
    first_aov = 2 if alpha else 1
    weight = count      # marks the weight channel: no source in the image
    sources = [0, 0, 0] + ([1] if alpha else []) + [weight] + list(range(first_aov, count))
    index = dr.arange(mi.UInt32, height * width * len(sources))
    pixel, source = index // len(sources), dr.gather(mi.UInt32, mi.UInt32(sources), index % len(sources))
    value = dr.gather(mi.Float, image.array, pixel * count + source, source != weight)
    return mi.TensorXf(dr.select(source == weight, 1.0, value) * spp, (height, width, len(sources)))


class _SceneSetup:
    """What one render needs from the scene: specimen media, shape lookup, polariscope."""

    def __init__(self, scene, sensor, right=None):
        self.media = []
        shape_media = {}
        bounds = mi.ScalarBoundingBox3f()
        for shape in scene.shapes():
            medium = shape.interior_medium()
            if medium is not None and hasattr(medium, "phase_tensor"):
                bounds.expand(shape.bbox())
                shape_id = int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))[0])
                _require_closed(shape, shape_id)
                if medium not in self.media:
                    self.media.append(medium)
                shape_media[shape_id] = self.media.index(medium) + 1
        if not self.media:
            raise SceneSetupError('photoelastic: the scene has no specimen: add a shape with '
                                  '<medium type="stress" name="interior"> inside it')
        # No line crosses the specimens for longer: the bound on any ray's path inside them.
        self.specimen_diagonal = float(dr.norm(bounds.extents()))
        table = np.zeros(max(shape_media) + 1, dtype=np.uint32)
        for shape_id, index in shape_media.items():
            table[shape_id] = index
        self.medium_of_shape = mi.UInt32(table)

        lights = [e for e in scene.emitters() if hasattr(e, "polarizer")]
        if len(lights) != 1:
            raise SceneSetupError(f"photoelastic: the scene needs exactly one "
                                  f'<emitter type="polariscope_light">, found {len(lights)}')
        light = lights[0]
        self.radiance = light.radiance
        self.polariscope = Polariscope(polarizer=light.polarizer, input_qwp=light.qwp,
                                       output_qwp=getattr(sensor, "qwp", None),
                                       analyzer=getattr(sensor, "analyzer", None))
        if right is None:
            right = sensor.world_transform() @ mi.Vector3f(-1, 0, 0)
        self._right = dr.normalize(mi.Vector3f(right))
        # One camera's rays are coherent: Embree traced them 3.7x faster flagged so (512², the disk). A batch
        # drawn across views is not: flagged coherent, the kitten's training batches traced 4 to 6% slower.
        self.coherent_rays = sensor is not None

    def projection_coefficients(self, d):
        """Per ray, what turns :meth:`phase_tensor` into the step generator ``(p, q)``.

        The basis (u, v) is image right/up made perpendicular to the light
        direction -d. With a single medium its phase rate is folded in here,
        once per ray, instead of scaling six components at every step.
        """
        alpha, beta = projection.projection_coefficients(*projection.transverse_basis(-d, self._right))
        if len(self.media) == 1:
            rate = self.media[0].phase_rate
            alpha, beta = tuple(rate * a for a in alpha), tuple(rate * b for b in beta)
        return alpha, beta

    def phase_tensor(self, medium, p):
        """Stress at ``p`` of each ray's medium; scaled by its phase rate unless folded in above."""
        if len(self.media) == 1:
            return self.media[0].stress(p)
        return dr.switch(medium - 1, [m.phase_tensor for m in self.media], p)


mi.register_integrator("photoelastic", lambda props: PhotoelasticIntegrator(props))
