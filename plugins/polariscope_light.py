from __future__ import annotations

import math

import mitsuba as mi

from .properties import angle_property


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

     * - radiance
       - |float|
       - Intensity behind LP1; intensities are normalised so that free space
         between parallel polarisers gives this value. (Default: 1)

    A diffuse panel filling the whole background, as in a transmission
    polariscope: every camera ray ends on it. Its optics are read by the
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
        self.polarizer = angle_property(props, "polarizer", 90.0)
        self.qwp = angle_property(props, "qwp", None)
        self.radiance = float(props.get("radiance", 1.0))
        if not (math.isfinite(self.radiance) and self.radiance >= 0):
            raise ValueError(f"polariscope_light: 'radiance' must be finite and >= 0, got {self.radiance}")
        self.m_flags = mi.EmitterFlags.Infinite

    def to_string(self) -> str:
        return f"PolariscopeLight[polarizer={self.polarizer}, qwp={self.qwp}, radiance={self.radiance}]"


mi.register_emitter("polariscope_light", lambda props: PolariscopeLight(props))
