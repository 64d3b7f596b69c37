from __future__ import annotations

import mitsuba as mi

from mi_nest.tracer.parts import PolariscopeCameraPart

from mi_nest.physics.bands import parse_bands
from mi_nest.physics.polariscope import standard_polariscope

from .properties import angle_property, optics_property
from .stress import resolve_path

_PROJECTIONS = ("orthographic", "perspective")
_OWN_PROPERTIES = ("projection", "analyzer", "qwp", "optics", "bands")
# A camera's ``bands`` for one channel (no colour filters).
MONOCHROME = "monochrome"


class PolariscopeCamera(mi.Sensor):
    r"""
    .. _sensor-polariscope:

    Polariscope camera (:monosp:`polariscope`)
    ------------------------------------------

    .. pluginparameters::

     * - projection
       - |string|
       - ``orthographic`` (default) or ``perspective``; every other property
         (``to_world``, ``fov``, ``near_clip``, film, sampler...) is passed to
         Mitsuba's camera of that name, so both behave exactly like Mitsuba's.

     * - analyzer
       - |float|
       - Transmission axis alpha_2 of the analyser LP2 in degrees in the
         (u = image right, v = image up) plane; leave out for no analyser.
         (Default: 0)

     * - qwp
       - |float|
       - Fast axis beta_2 of the camera-side quarter-wave plate QWP2 in degrees;
         leave out for a plane polariscope. (Default: none)

     * - optics
       - |string|
       - Instead of ``qwp`` and ``analyzer``: the elements between the specimen
         and the camera in the order the light meets them, written as the
         ``polariscope_light``'s ``optics`` (e.g. ``"compensator 45 360 0.25;
         polarizer 0"``); empty for none. (Default: none)

     * - bands
       - |string|
       - A colour camera's bands: ``rgb`` (an RGB sensor's curves,
         docs/datasets.md), wavelengths in nm (``450,532,650``: narrow
         filters) or a CSV file of the sensor's curves, seen under the light
         panel's ``spectrum`` (the white LED when it names none);
         ``monochrome`` for one channel. ``mi-nest render`` then gives each
         band's image and its 16 measurements, and ``mi-nest simulate`` a
         dataset in those bands. (Default: monochrome)

    The camera half of the polariscope. With the ``polariscope_light`` emitter it
    defines the main channel of the ``photoelastic`` integrator.

    .. tabs::

        .. code-tab:: xml

            <sensor type="polariscope">
                <string name="projection" value="orthographic"/>
                <float name="qwp" value="135"/>
                <float name="analyzer" value="0"/>
                <transform name="to_world">
                    <scale value="25"/>
                    <lookat origin="0, 0, 100" target="0, 0, 0" up="0, 1, 0"/>
                </transform>
                <film type="hdrfilm"> ... </film>
            </sensor>
    """

    def __init__(self, props):
        super().__init__(props)
        projection = props.get("projection", "orthographic")
        if projection not in _PROJECTIONS:
            raise ValueError(f"polariscope: unknown projection '{projection}'; choose one of {_PROJECTIONS}")
        self.projection = projection
        self.optics = optics_property(props, "optics", "polariscope", ("analyzer", "qwp"))
        if self.optics is None:
            self.optics = standard_polariscope(output_qwp=angle_property(props, "qwp", None),
                                               analyzer=angle_property(props, "analyzer", 0.0)).camera
        self.bands = _bands(props)
        camera = {key: props[key] for key in props.keys()
                  if key not in _OWN_PROPERTIES and not isinstance(props[key], (mi.Film, mi.Sampler))}
        camera.update(type=projection, film=self.film(), sampler=self.sampler())
        self.camera = mi.load_dict(camera)

    def sample_ray(self, time: mi.Float, sample1: mi.Float, sample2: mi.Point2f, sample3: mi.Point2f,
                   active: mi.Bool = True) -> tuple[mi.Ray3f, mi.Spectrum]:
        return self.camera.sample_ray(time, sample1, sample2, sample3, active)

    def sample_ray_differential(self, time: mi.Float, sample1: mi.Float, sample2: mi.Point2f, sample3: mi.Point2f,
                                active: mi.Bool = True) -> tuple[mi.RayDifferential3f, mi.Spectrum]:
        return self.camera.sample_ray_differential(time, sample1, sample2, sample3, active)

    def world_transform(self) -> mi.Transform4f:
        return self.camera.world_transform()

    def to_string(self) -> str:
        optics = "; ".join(element.describe() for element in self.optics)
        bands = "" if self.bands is None else f", bands={self.bands}"
        return f"PolariscopeCamera[projection={self.projection}, optics={optics}{bands}]"


def _bands(props) -> str | None:
    """The ``bands`` text (a CSV's path resolved), checked now under the default light; None: monochrome."""
    text = str(props.get("bands", MONOCHROME)).strip()
    if text.lower() == MONOCHROME:
        return None
    if text.lower().endswith(".csv"):
        text = resolve_path(text)
    try:
        parse_bands(text)
    except ValueError as error:
        raise ValueError(f"polariscope: 'bands': {error}") from None
    return text


PolariscopeCameraPart.register(PolariscopeCamera)
mi.register_sensor("polariscope", lambda props: PolariscopeCamera(props))
