from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import mitsuba as mi
import numpy as np

from mi_nest.fields import MODELS, FieldParameterError
from mi_nest.fields.base import sample as sample_field
from mi_nest.physics.dispersion import Constant, Table, parse_dispersion
from mi_nest.physics.tensors import Tensor, Vector
from mi_nest.tracer.parts import StressMediumPart


class StressMedium(mi.Medium):
    r"""
    .. _medium-stress:

    Photoelastic stress medium (:monosp:`stress`)
    ---------------------------------------------

    .. pluginparameters::

     * - stress_optic_coefficient
       - |float|
       - Stress-optic coefficient C in Brewster (1e-12 / Pa). Give this or
         ``fringe_value``.

     * - fringe_value
       - |float|
       - Material fringe value f_sigma = lambda / C in N/mm (MPa mm).

     * - wavelength
       - |float|
       - Wavelength in nm. (Default: 532, the rig's bandpass filter)

     * - dispersion
       - |string|
       - How C changes with the wavelength, for views at other wavelengths:
         ``constant``, ``cauchy B`` (``C = A + B / lambda^2``, B in Brewster
         nm^2, A set by C at ``wavelength``) or ``table L1 C1 L2 C2 ...``
         (C in Brewster measured at L in nm, linear between; it then gives C
         at ``wavelength`` itself, so leave out ``stress_optic_coefficient``
         and ``fringe_value``). (Default: constant)

     * - filename
       - |string|
       - Stress file: a grid ``.npz`` (``stress`` (Z, Y, X, 6) in MPa, 3D-TSV
         order xx, yy, zz, yz, zx, xy, ``bbox_min``/``bbox_max`` in mm), a mesh
         ``.npz`` (``nodes``, ``cells``, nodal ``stress``: FEM results) or a 3D-TSV
         file (``.TSV``, ``.TSVcarti``, early ``.stress``, ``.carti``). Meshes are resampled onto a grid; lookups are
         trilinear and differentiable through ``mi.traverse`` as ``stress``.

     * - grid_resolution
       - |int|
       - Grid nodes along the longest axis when resampling a mesh. (Default: 64)

     * - model
       - |string|
       - Closed-form field instead of a file: ``uniform``, ``twisted``,
         ``disk_compression``, ``stacked_disks``, ``lame_cylinder``,
         ``shaft_torsion``, ``beam_bending``, ``kirsch_plate`` or ``boussinesq``;
         its parameters (see ``mi_nest.fields.analytic``) are given as further
         properties.

    The interior of the enclosing (closed, outward-oriented) shape holds a
    stress field in MPa; scene lengths are mm, so the retardance of a constant
    step of length L is ``2 pi C L (sigma_1 - sigma_2) / lambda`` with no other
    factor. Occupancy is the shape itself. Only the ``photoelastic`` integrator
    reads this medium: it samples its ``field`` at ``phase_rate`` per mm
    (``mi_nest.tracer.setup``), or a field the caller passes in its place.

    .. tabs::

        .. code-tab:: xml

            <shape type="ply">
                <string name="filename" value="meshes/disk.ply"/>
                <medium type="stress" name="interior">
                    <float name="fringe_value" value="10.6"/>
                    <string name="model" value="disk_compression"/>
                    <float name="diameter" value="40"/>
                    <float name="thickness" value="6"/>
                    <float name="load" value="1000"/>
                </medium>
            </shape>
    """

    def __init__(self, props):
        super().__init__(props)
        self.wavelength = _positive(props, "wavelength", 532.0)
        try:
            self.dispersion = parse_dispersion(str(props["dispersion"])) if "dispersion" in props else Constant()
        except ValueError as error:
            raise ValueError(f"stress medium: {error}") from None
        has_c, has_f = "stress_optic_coefficient" in props, "fringe_value" in props
        if isinstance(self.dispersion, Table):
            if has_c or has_f:
                raise ValueError("stress medium: a dispersion table gives C at the medium's wavelength too; leave "
                                 "out 'stress_optic_coefficient' and 'fringe_value'")
            try:
                self.stress_optic_coefficient = self.dispersion.coefficient(self.wavelength)
            except ValueError as error:
                raise ValueError(f"stress medium: {error}") from None
        elif has_c == has_f:
            raise ValueError("stress medium: give exactly one of 'stress_optic_coefficient' "
                             "(Brewster) or 'fringe_value' (N/mm)")
        elif has_c:
            self.stress_optic_coefficient = _positive(props, "stress_optic_coefficient", None)
        else:
            self.stress_optic_coefficient = self.wavelength / _positive(props, "fringe_value", None)
        # rad per (MPa mm): Brewster * MPa * mm / nm = 1.
        self.phase_rate = math.pi * self.stress_optic_coefficient / self.wavelength
        self.field = _field_from_properties(props)

    @property
    def fringe_value(self) -> float:
        return self.wavelength / self.stress_optic_coefficient

    def dispersion_factor(self, wavelength: float) -> float:
        """``C(wavelength) / C``: how much the stress-optic coefficient changes from the medium's wavelength."""
        if isinstance(self.dispersion, Constant):
            return 1.0
        at = self.dispersion.coefficient(wavelength, self.wavelength, self.stress_optic_coefficient)
        return at / self.stress_optic_coefficient

    def stress(self, p: Vector) -> Tensor:
        """Stress tensor (MPa, 3D-TSV 6-tuple) at points ``p`` (mm)."""
        return self.field.eval(p)

    def sample(self, points: np.ndarray) -> np.ndarray:
        """Stress (MPa) at NumPy points ``(N, 3)`` (mm) as an ``(N, 6)`` NumPy array."""
        return sample_field(self.field, points)

    def traverse(self, callback: mi.TraversalCallback) -> None:
        self.field.traverse(callback)

    def parameters_changed(self, keys: list[str]) -> None:
        self.field.parameters_changed(keys)

    def to_string(self) -> str:
        return (f"StressMedium[C={self.stress_optic_coefficient:g} B, wavelength={self.wavelength:g} nm, "
                f"dispersion={self.dispersion.describe()}, field={self.field!r}]")


def resolve_path(filename: str | Path) -> str:
    """A file name as Mitsuba resolves it: relative to the scene file being loaded."""
    return str(mi.file_resolver().resolve(str(filename)))


def _positive(props, name, default):
    if name not in props and default is not None:
        return default
    value = float(props[name])
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"stress medium: '{name}' must be a positive number, got {value}")
    return value


def _field_from_properties(props):
    has_file, has_model = "filename" in props, "model" in props
    if has_file == has_model:
        raise ValueError("stress medium: give exactly one of 'filename' (a stress grid .npz) "
                         f"or 'model' (one of {sorted(MODELS)})")
    if has_file:
        from mi_nest.fields.grid import GridField
        from mi_nest.fields.sources import grid_from_file
        resolution = int(props.get("grid_resolution", 64))
        if resolution < 2:
            raise ValueError(f"stress medium: 'grid_resolution' must be at least 2, got {resolution}")
        return GridField(grid_from_file(resolve_path(props["filename"]), resolution))
    name = props["model"]
    if name not in MODELS:
        raise ValueError(f"stress medium: unknown model '{name}'; available: {sorted(MODELS)}")
    model = MODELS[name]
    kwargs = {}
    for parameter in dataclasses.fields(model):
        if parameter.init and parameter.name in props:
            kwargs[parameter.name] = _parameter_value(name, parameter, props[parameter.name])
    try:
        return model(**kwargs)
    except FieldParameterError as error:
        raise ValueError(f"stress medium (model '{name}'): {error}") from None


def _parameter_value(model, parameter, value):
    if isinstance(parameter.default, tuple):
        try:
            return tuple(float(value[i]) for i in range(3))
        except (TypeError, IndexError):
            raise ValueError(f"stress medium (model '{model}'): '{parameter.name}' must be a "
                             f"3-vector (<vector>/<point>), got {value!r}") from None
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"stress medium (model '{model}'): '{parameter.name}' must be a number, "
                         f"got {value!r}") from None


StressMediumPart.register(StressMedium)
mi.register_medium("stress", lambda props: StressMedium(props))
