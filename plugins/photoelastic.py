from __future__ import annotations

import contextlib
from dataclasses import replace
from typing import Any, Iterator, get_type_hints

import drjit as dr
import mitsuba as mi

from mi_nest.fields import StressField
from mi_nest.physics.aliasing import FringeAliasing
from mi_nest.tracer import film as films
from mi_nest.tracer import guards
from mi_nest.tracer.film import CHANNELS
from mi_nest.tracer.methods import Decision
from mi_nest.tracer.registry import METHODS, require_adjoint
from mi_nest.tracer.tracer import SCENE_VIEW, TracePlan, Tracer, TracerConfig, View

# The properties: TracerConfig's fields, each read as its type.
PROPERTIES = get_type_hints(TracerConfig)


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
         Where surfaces refract, a ray that would cross more (trapped by total
         internal reflection) brings no light. (Default: 64)

     * - max_bounces
       - |int|
       - Where surfaces refract: most partial reflections followed per ghost
         path. Each sample then also walks one path that chooses at random,
         at every crossing, reflection or transmission, and adds its
         intensity (unbiased for the ghosts of up to ``max_bounces``
         reflections); 0 follows the transmitted path alone. Ray batches
         carry the ghost too, so reconstruction models what renders show
         (docs/refraction.md). (Default: 4)

    Renders integrated photoelasticity (docs/physics.md): for every camera ray it
    follows the light from the ``polariscope_light`` panel to the camera through
    every shape whose interior is a ``stress`` medium, entering and leaving as
    often as the geometry requires (entry where the ray meets the outside of a
    surface, exit at the next crossing; specimens may touch face to face, but
    not nest), and multiplies the exact exponential
    of each constant-stress step as an SU(2) quaternion, renormalised at every
    step. Any other shape is opaque, unless its surface is a smooth
    ``dielectric`` (an immersion bath).

    A specimen or bath whose surface carries ``<bsdf type="dielectric">``
    refracts: the walk follows Snell's law at it and multiplies in the Fresnel
    transmission as a Jones matrix in the ray's transverse frame, carried along
    the bent path without twist; total internal reflection reflects the ray
    with its phases (docs/physics.md section 8, ``mi_nest/tracer/
    refraction.py``). The Jones channels then hold the specimens' own product
    and the intensities the whole path's. Ray batches (``Tracer.trace_rays``)
    then hold the path's matrix, and ``backpropagate_rays`` replays it
    (``product`` and ``magnus4``); ``render_backward`` is not available
    through refracting surfaces. With ``max_bounces`` each sample adds a ghost
    path's intensities, in renders and ray batches alike (16 numbers then).

    The film receives the intensity of the scene's polariscope as its main
    channel (``Y``) and, as named channels, the Jones product
    ``jones.a/b/c/d``, its characteristic parameters ``char.delta``,
    ``char.theta``, ``char.gamma`` (radians), the 16 normalised intensities
    ``pol.<b1>.<b2>.<a2>`` of the multi-axis polariscope, ``fringe.order`` (the
    linear model's unwrapped fringe order: exact where the axes do not turn
    along the ray) and ``path.length``, the length (mm) of the ray's path
    inside specimens. After each render it measures the fringe density from
    ``fringe.order`` and warns where fringes are denser than the pixel grid
    (:meth:`render_with_aliasing` returns the report with the image).

    A render with a spectral view (``View`` lanes: what ``render_white_light``
    and ``render_bands`` pass) marches several wavelengths at once, the stress
    looked up once per step for all (``mi_nest/tracer/spectral.py``): the
    channels above are the first wavelength's, and each wavelength adds its
    main intensity (and, by the view's ``lane_outputs``, its 16 measurements or its Jones product) after them.

    .. tabs::

        .. code-tab:: xml

            <integrator type="photoelastic">
                <float name="step_size" value="0.25"/>
            </integrator>
    """

    def __init__(self, props):
        mi.CppADIntegrator.__init__(self, props)
        given = {name: props.get(name) for name in PROPERTIES if name in props}
        self.tracer = Tracer(TracerConfig(**{name: PROPERTIES[name](value) for name, value in given.items()}))
        if "points" in given and not self.tracer.method.takes_points:
            takers = " and ".join(f"'{name}'" for name, cls in METHODS.items() if getattr(cls, "takes_points", False))
            raise ValueError(f"photoelastic: 'points' applies to method {takers} only, not "
                             f"'{self.tracer.config.method}'")
        self._plan = None       # what the render in progress shares with sample(): Mitsuba's render calls it

    def configure(self, **changes) -> None:
        """Change properties between renders (``integrator.configure(method="auto")``): a new tracer."""
        self.tracer = Tracer(replace(self.tracer.config, **changes))

    def aov_names(self) -> list[str]:
        # During a spectral render, its wavelengths' channels follow (Mitsuba's render asks while it prepares).
        return list(CHANNELS) + list(self._plan.lanes if self._plan is not None else ())

    def to_string(self) -> str:
        config = self.tracer.config
        return (f"PhotoelasticIntegrator[method={config.method}, step_size={config.step_size:g} mm, "
                f"points={config.points}, jitter={config.jitter}, max_crossings={config.max_crossings}, "
                f"max_bounces={config.max_bounces}]")

    def channel_names(self, film: mi.Film, view: View = SCENE_VIEW) -> list[str]:
        """Names of the channels of the image :meth:`render` returns with ``view``, in order."""
        return films.channel_names(film, view.lane_channels)

    def check_scene(self, scene: mi.Scene, sensor: int | mi.Sensor = 0) -> None:
        """Raise :class:`~mi_nest.tracer.guards.SceneSetupError` naming what the scene lacks.

        ``mi.render`` reports exceptions raised inside ``render`` only as a failed
        custom operation, so callers that want the message check first.
        """
        self.tracer.plan(scene, _sensor(scene, sensor))     # what render prepares, the step count included

    def decide(self, scene: mi.Scene, sensor: int | mi.Sensor = 0, field: StressField | None = None,
               view: View = SCENE_VIEW) -> Decision:
        """The method and step a render marches with (:meth:`Tracer.decide`), to pass to several passes."""
        return self.tracer.decide(scene, _sensor(scene, sensor), field, view)

    def render(self, scene: mi.Scene, sensor: int | mi.Sensor = 0, seed: int = 0, spp: int = 0, develop: bool = True,
               evaluate: bool = True) -> mi.TensorXf:
        if not develop:
            raise ValueError("photoelastic: develop=True must be specified")
        return self.render_with_aliasing(scene, sensor, seed, spp)[0]

    def render_with_aliasing(self, scene: mi.Scene, sensor: int | mi.Sensor = 0, seed: int = 0, spp: int = 0,
                             field: StressField | None = None, view: View = SCENE_VIEW,
                             decision: Decision | None = None) -> tuple[mi.TensorXf, FringeAliasing]:
        """:meth:`render`, and the aliasing guard's report on the image.

        ``field``, if given, is rendered in every specimen instead of its own
        stress (a reconstruction's field); the specimens keep their material.
        ``view`` changes the polariscope and the phases; ``decision`` (from
        :meth:`decide`) is the method and step to march with.
        """
        sensor = _sensor(scene, sensor)
        with self._planned(scene, sensor, field, view, decision) as plan:
            if films.sums_pixels_directly(sensor.film()):
                image, guarded = self._render_pixel_sums(scene, sensor, seed, spp)
            else:
                image = super().render(scene, sensor, seed, spp)
                guarded = films.guarded_channels(image, len(plan.lanes))
            if plan.norm_error is not None:
                guards.warn_if_not_unitary(float(plan.norm_error[0]), plan.decision.step_size)
            return image, guards.check_aliasing(*guarded)

    def render_backward(self, scene: mi.Scene, params: Any, grad_in: mi.TensorXf, sensor: int | mi.Sensor = 0,
                        seed: int = 0, spp: int = 0) -> None:
        """Reverse-mode derivative of :meth:`render` by path replay: memory does not grow with the steps.

        ``grad_in`` is the adjoint of the developed image; every channel but
        ``fringe.order`` and ``path.length`` propagates to the field.
        """
        sensor = _sensor(scene, sensor)
        if not films.sums_pixels_directly(sensor.film()):
            raise ValueError("photoelastic: differentiable rendering needs a box-filtered film "
                             '(<rfilter type="box"/>) without border')
        with self._planned(scene, sensor) as plan, dr.suspend_grad():
            guards.refuse_refraction(plan.setup, "differentiable rendering")
            require_adjoint(plan.decision.method)
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

    def render_forward(self, scene: mi.Scene, params: Any, sensor: int | mi.Sensor = 0, seed: int = 0,
                       spp: int = 0) -> mi.TensorXf:
        raise NotImplementedError("photoelastic: forward-mode derivatives are not available; differentiate in "
                                  "reverse mode (dr.backward on the rendered image)")

    def sample(self, mode: dr.ADMode, scene: mi.Scene, sampler: mi.Sampler, ray: mi.Ray3f, active: mi.Bool,
               δL: mi.Spectrum | None = None, δaovs: list[mi.Float] | None = None, state_in: tuple | None = None,
               **kwargs) -> tuple:
        if mode == dr.ADMode.Primal:
            main, aovs, state = self.tracer.trace_samples(self._plan, scene, sampler, ray, active)
            return main, mi.Bool(True), aovs, state
        if mode != dr.ADMode.Backward:
            raise NotImplementedError("photoelastic: forward-mode derivatives are not available")
        self.tracer.replay_samples(self._plan, scene, sampler, ray, active, δL, δaovs, state_in)
        return mi.Spectrum(0), mi.Bool(True), [mi.Float(0)] * len(CHANNELS), None

    @contextlib.contextmanager
    def _planned(self, scene, sensor, field=None, view=SCENE_VIEW, decision=None) -> Iterator[TracePlan]:
        self._plan = self.tracer.plan(scene, sensor, field=field, view=view, decision=decision)
        try:
            yield self._plan
        finally:
            self._plan = None

    def _render_pixel_sums(self, scene, sensor, seed, spp):
        """``ADIntegrator.render`` for box-filtered films, without per-sample atomics (see ``film``)."""
        with dr.suspend_grad():
            sampler, spp = self.prepare(sensor, seed, spp, self.aov_names())
            ray, weight, _ = self.sample_rays(scene, sensor, sampler)
            main, _, aovs, _ = self.sample(dr.ADMode.Primal, scene, sampler, ray, mi.Bool(True))
            return films.develop_pixel_sums(sensor.film(), spp, (main * weight)[0], aovs)


def _sensor(scene: mi.Scene, sensor: int | mi.Sensor) -> mi.Sensor:
    return scene.sensors()[sensor] if isinstance(sensor, int) else sensor


mi.register_integrator("photoelastic", lambda props: PhotoelasticIntegrator(props))
