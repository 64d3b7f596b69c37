from __future__ import annotations

import math

import mitsuba as mi

from mi_nest.tracer.parts import PolariscopeLightPart

from mi_nest.physics.colour import MONOCHROMATIC, parse_light
from mi_nest.physics.polariscope import Polarizer, standard_polariscope

from .properties import angle_property, optics_property
from .stress import resolve_path


class PolariscopeLight(mi.Emitter):
    r"""
    .. _emitter-polariscope_light:

    Polarised light panel (:monosp:`polariscope_light`)
    ---------------------------------------------------

    .. pluginparameters::

     * - polarizer
       - |float|
       - Transmission axis alpha_1 of the source polariser LP1 in degrees, in the
         transverse (u = image right, v = image up) plane of each ray. (Default: 90)

     * - qwp
       - |float|
       - Fast axis beta_1 of the source-side quarter-wave plate QWP1 in degrees;
         leave out for a plane polariscope. (Default: none)

     * - optics
       - |string|
       - Instead of ``polarizer`` and ``qwp``: the elements between the panel and
         the specimen in the order the light meets them, a polariser first,
         e.g. ``"polarizer 90; hwp 22.5; qwp 45"``; each element is ``polarizer
         ANGLE``, ``qwp ANGLE``, ``hwp ANGLE``, ``waveplate ANGLE RETARDANCE``
         or ``compensator ANGLE RATE POSITION`` (a Babinet-Soleil compensator:
         RATE degrees of retardance per mm of its micrometer, at POSITION mm),
         angles and retardances in degrees. (Default: none)

     * - radiance
       - |float|
       - Intensity behind LP1; intensities are normalised so that free space
         between parallel polarisers gives this value. (Default: 1)

     * - size
       - |float|
       - Side (mm) of a square panel facing the camera; leave out for a panel
         filling the whole background. (Default: none)

     * - distance
       - |float|
       - With ``size``: how far (mm) behind the specimens' centre the panel
         lies, along the camera's axis. (Default: 100)

     * - spectrum
       - |string|
       - The panel's light: ``monochromatic`` (one wavelength, the specimens'
         media's), ``white_led`` (CIE LED-B3, a phosphor white LED) or a CSV
         file ``wavelength,power`` (relative spectral power, nm; resolved as
         Mitsuba resolves file names). ``mi-nest render`` and ``slice`` then
         show it in colour, and a colour camera's bands (the ``polariscope``
         sensor's ``bands``) are seen under it; the integrator's own render
         stays at the media's wavelength (docs/physics.md section 9).
         (Default: monochromatic)

    A diffuse panel, as in a transmission polariscope: by default it fills the
    whole background and every camera ray ends on it. With ``size`` it is a
    square of that side facing the camera ``distance`` behind the specimens:
    a ray that refraction bends past its edge carries nothing (the dark rim of
    a real part in air). Its optics are read by the
    ``photoelastic`` integrator, which rotates them with the camera (the whole
    polariscope turns around the fixed specimen).

    .. tabs::

        .. code-tab:: xml

            <emitter type="polariscope_light">
                <float name="polarizer" value="90"/>
                <float name="qwp" value="45"/>
            </emitter>
    """

    def __init__(self, props):
        super().__init__(props)
        self.optics = optics_property(props, "optics", "polariscope_light", ("polarizer", "qwp"))
        if self.optics is None:
            self.optics = standard_polariscope(polarizer=angle_property(props, "polarizer", 90.0),
                                               input_qwp=angle_property(props, "qwp", None)).light
        elif not isinstance(self.optics[0], Polarizer):
            raise ValueError(f"polariscope_light: 'optics' starts with the panel's polariser, got "
                             f"'{props['optics']}'")
        self.polarizer = self.optics[0].angle       # the panel's polariser, which datasets record
        self.radiance = float(props.get("radiance", 1.0))
        if not (math.isfinite(self.radiance) and self.radiance >= 0):
            raise ValueError(f"polariscope_light: 'radiance' must be finite and >= 0, got {self.radiance}")
        self.size = _optional_length(props, "size", None)
        self.distance = _optional_length(props, "distance", 100.0)
        self.spectrum = _spectrum(props)
        self.m_flags = mi.EmitterFlags.Infinite

    def to_string(self) -> str:
        panel = "" if self.size is None else f", size={self.size}, distance={self.distance}"
        optics = "; ".join(element.describe() for element in self.optics)
        light = "" if self.spectrum is None else f", spectrum={self.spectrum.name}"
        return f"PolariscopeLight[optics={optics}, radiance={self.radiance}{panel}{light}]"


def _spectrum(props):
    text = str(props.get("spectrum", MONOCHROMATIC))
    try:
        return parse_light(resolve_path(text) if text.strip().lower().endswith(".csv") else text)
    except ValueError as error:
        raise ValueError(f"polariscope_light: 'spectrum': {error}") from None


def _optional_length(props, name, default):
    if name not in props:
        return default
    value = float(props[name])
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"polariscope_light: '{name}' must be a positive length in mm, got {value}")
    return value


PolariscopeLightPart.register(PolariscopeLight)
mi.register_emitter("polariscope_light", lambda props: PolariscopeLight(props))
