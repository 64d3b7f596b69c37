"""Virtual slicing: the fringes of a slab cut out of the part, with its stress frozen, seen at normal incidence.

A photoelastician freezes the stress, saws a slab and looks through it in a
polariscope. Here the slab is a plane and a thickness: every pixel's line runs
along the plane's normal, the chords where it lies inside the slab, inside a
specimen and inside an optional region (a box or a closed mesh) are found
exactly (ray-traced crossings, NumPy interval algebra), and the integrator
marches them as it marches its own segments (``trace_chords``): the same steps,
fields and polariscope. No surface refracts: a sawn slab is viewed in an
immersion bath, at normal incidence.

The camera stands on the normal's side and looks back along it, image right
and up fixed by :meth:`Plane.basis`; the light travels along the normal.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import mitsuba as mi
import numpy as np

from .. import occupancy
from ..arguments import whole_number
from ..arrays import device_array
from ..physics.colour import Spectrum
from ..physics.polariscope import Polariscope, polariscope_setting
from ..render import (RenderResult, WavelengthRenders, check_light_and_load, in_white_light, phase_scale,
                      require_memory)
from ..scene import photoelastic_integrator, specimen_bounds, specimen_media, specimen_shapes
from ..tracer import View
from ..version import __version__

AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
# Steps per slab thickness at least: a field that varies through the slab is marched finely however long the
# scene's step is.
STEPS_PER_THICKNESS = 8
# Peak memory of a slice per pixel: 355 to 520 bytes measured on the disk (across and along its axis), the
# stacked disks and the kitten from 1.5e5 to 4e6 pixels.
SLICE_BYTES_PER_PIXEL = 600
# Mesh files a region can be.
REGION_MESH_SUFFIXES = {".ply": "ply", ".obj": "obj", ".stl": "stl"}
REGION_HELP = "box:X0,Y0,Z0,X1,Y1,Z1 (mm, two opposite corners) or a closed mesh file (.ply, .obj, .stl)"


class SliceError(ValueError):
    """A slice that cannot be made: bad plane, thickness or region, or one that holds none of the part."""


@dataclass(frozen=True)
class Plane:
    """The points ``p`` with ``normal . p = offset`` (mm); ``normal`` is a unit vector."""
    normal: tuple
    offset: float = 0.0

    def __post_init__(self):
        normal = np.asarray(self.normal, dtype=np.float64).ravel()
        if normal.shape != (3,) or not np.all(np.isfinite(normal)) or np.linalg.norm(normal) < 1e-9:
            raise SliceError(f"the slice normal must be three finite numbers, not all zero; got {self.normal}")
        if not math.isfinite(self.offset):
            raise SliceError(f"the slice offset must be a finite number of mm, got {self.offset}")
        object.__setattr__(self, "normal", tuple(float(x) for x in normal / np.linalg.norm(normal)))
        object.__setattr__(self, "offset", float(self.offset))

    @classmethod
    def parse(cls, plane: str | None = None, normal: str | None = None, offset: float | None = None) -> Plane:
        """From ``--plane z=0`` (an axis and where it is cut), or ``--normal x,y,z`` with ``--offset mm``."""
        if (plane is None) == (normal is None):
            raise SliceError("give the slice as --plane AXIS=MM (for example z=0) or as --normal X,Y,Z "
                             "[--offset MM], not both")
        if plane is not None:
            if offset is not None:
                raise SliceError("--offset goes with --normal; with --plane the offset is the value after '='")
            axis, sep, value = plane.partition("=")
            axis = axis.strip().lower()
            if not sep or axis not in AXES:
                raise SliceError(f"--plane must be x=MM, y=MM or z=MM, got '{plane}'")
            return cls(AXES[axis], _number(value, "--plane"))
        try:
            components = tuple(float(x) for x in normal.split(","))
        except ValueError:
            components = ()
        if len(components) != 3:
            raise SliceError(f"--normal must be three comma-separated numbers X,Y,Z, got '{normal}'")
        return cls(components, 0.0 if offset is None else float(offset))

    def basis(self) -> tuple[np.ndarray, np.ndarray]:
        """Image right and up, ``right x up = normal``: for ``z = c``, x and y; up is the world's y (z for
        a plane across y) made perpendicular to the normal."""
        n = np.asarray(self.normal)
        hint = np.array([0.0, 1.0, 0.0]) if abs(n[1]) < 0.9 else np.array([0.0, 0.0, 1.0])
        right = np.cross(hint, n)
        right /= np.linalg.norm(right)
        return right, np.cross(n, right)

    def describe(self) -> str:
        for axis, direction in AXES.items():
            if np.allclose(self.normal, direction):
                return f"{axis} = {self.offset:g} mm"
        return f"normal ({', '.join(f'{x:.3g}' for x in self.normal)}) . p = {self.offset:g} mm"


@dataclass(frozen=True)
class Region:
    """Part of the volume a slice keeps: an axis-aligned box (mm), or the inside of a closed mesh file."""
    low: tuple | None = None
    high: tuple | None = None
    mesh: Path | None = None

    @classmethod
    def parse(cls, text: str) -> Region:
        if text.startswith("box:"):
            try:
                values = [float(x) for x in text[4:].split(",")]
            except ValueError:
                values = []
            if len(values) != 6 or not all(map(math.isfinite, values)):
                raise SliceError(f"--region box needs six numbers X0,Y0,Z0,X1,Y1,Z1 (mm), got '{text}'")
            corners = np.array(values).reshape(2, 3)
            low, high = corners.min(axis=0), corners.max(axis=0)
            if np.any(high <= low):
                raise SliceError(f"--region box '{text}' is flat: its corners must differ along x, y and z")
            return cls(tuple(low), tuple(high))
        path = Path(text[5:] if text.startswith("mesh:") else text)
        if path.suffix.lower() not in REGION_MESH_SUFFIXES:
            raise SliceError(f"--region must be {REGION_HELP}; got '{text}'")
        if not path.is_file():
            raise SliceError(f"--region mesh file not found: {path}")
        return cls(mesh=path.resolve())

    def chords(self, starts: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(begin, end)`` (K, P): where each line ``starts + t d`` is inside the region."""
        if self.mesh is None:
            with np.errstate(divide="ignore", invalid="ignore"):
                t0 = (np.asarray(self.low) - starts) / d
                t1 = (np.asarray(self.high) - starts) / d
            parallel = np.abs(d) < 1e-12
            inside = (starts >= np.asarray(self.low)) & (starts <= np.asarray(self.high))
            near = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t0, t1))
            far = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t0, t1))
            begin, end = near.max(axis=1), far.min(axis=1)
            empty = end <= begin
            return np.where(empty, np.inf, begin)[None], np.where(empty, np.inf, end)[None]
        scene = mi.load_dict({"type": "scene", "region": {"type": REGION_MESH_SUFFIXES[self.mesh.suffix.lower()],
                                                          "filename": str(self.mesh)}})
        shape = scene.shapes()[0]
        crossings = occupancy.crossings_along_lines(scene, shape, starts, d)
        begin, end = _pairs(crossings)
        if np.any(np.isfinite(begin) & ~np.isfinite(end)):
            raise SliceError(f"--region mesh {self.mesh} is not closed: a line enters it and never leaves")
        return begin, end

    def describe(self) -> str:
        if self.mesh is not None:
            return f"inside {self.mesh.name}"
        return "box " + " to ".join("(" + ", ".join(f"{x:g}" for x in corner) + ")"
                                    for corner in (self.low, self.high))


@dataclass(frozen=True)
class SliceSpec:
    """A slab: its mid-plane and thickness (mm), optionally only inside ``region``; how it is looked at."""
    plane: Plane
    thickness: float
    region: Region | None = None
    resolution: int = 256               # pixels along the longer side of the part's outline
    polariscope: Polariscope = field(default_factory=polariscope_setting)
    load_scale: float = 1.0             # the stress times this
    wavelength: float | None = None     # nm; None: each medium's own

    def __post_init__(self):
        if not (math.isfinite(self.thickness) and self.thickness > 0):
            raise SliceError(f"the slice thickness must be a positive number of mm, got {self.thickness}")
        whole_number("resolution", self.resolution, minimum=2)
        check_light_and_load(self.load_scale, self.wavelength)      # before any scene is loaded

    def describe(self) -> str:
        return (f"slice {self.plane.describe()}, {self.thickness:g} mm thick"
                + ("" if self.region is None else f", {self.region.describe()}"))


@dataclass(frozen=True)
class SliceImage:
    """Where a slice's pixels are: centres ``origin + (col + 1/2) s right - (row + 1/2) s up`` on the plane."""
    origin: np.ndarray      # the image's top-left corner on the plane (mm)
    right: np.ndarray
    up: np.ndarray
    pixel: float            # mm
    width: int
    height: int

    def centres(self) -> np.ndarray:
        cols = (np.arange(self.width) + 0.5) * self.pixel
        rows = (np.arange(self.height) + 0.5) * self.pixel
        return (self.origin + cols[None, :, None] * self.right - rows[:, None, None] * self.up).reshape(-1, 3)

    def extent(self) -> tuple[float, float, float, float]:
        """``(left, right, bottom, top)`` in mm along the image axes (matplotlib's ``extent``)."""
        left = float(self.origin @ self.right)
        top = float(self.origin @ self.up)
        return left, left + self.width * self.pixel, top - self.height * self.pixel, top


def _bounding_corners(scene: mi.Scene) -> np.ndarray:
    """The eight corners (8, 3) of the specimens' bounding box."""
    low, high = specimen_bounds(specimen_shapes(scene))
    return np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])])


def slice_image(scene: mi.Scene, plane: Plane, resolution: int) -> SliceImage:
    """The pixels of ``plane`` that cover the specimens' outline projected onto it, ``resolution`` along its
    longer side."""
    resolution = whole_number("resolution", resolution, minimum=2)
    right, up = plane.basis()
    corners = _bounding_corners(scene)
    across, along = corners @ right, corners @ up
    pixel = max(np.ptp(across), np.ptp(along)) / resolution
    width, height = (max(int(math.ceil(np.ptp(a) / pixel - 1e-9)), 1) for a in (across, along))
    # Centred on the outline; the plane point is its offset along the normal.
    centre_across = 0.5 * (across.min() + across.max())
    centre_along = 0.5 * (along.min() + along.max())
    on_plane = plane.offset * np.asarray(plane.normal)
    origin = on_plane + (centre_across - 0.5 * width * pixel) * right + (centre_along + 0.5 * height * pixel) * up
    return SliceImage(origin, right, up, pixel, width, height)


def slice_render(scene: mi.Scene, spec: SliceSpec, field: object | None = None) -> RenderResult:
    """The slab's image: the named channels of a render (``Y`` through ``spec.polariscope``, the Jones product,
    ``fringe.order``: the isochromatic order, ...) plus ``isoclinic.angle`` (degrees from image right to
    sigma_1's direction in the image plane, in (-90, 90]) and ``slab.mask`` (1 where the slab holds part of a
    specimen). ``field``, if given, is shown in every specimen instead of its own stress (a reconstruction's).
    For many slices of one scene, keep a :class:`Slicer`."""
    return Slicer(scene).render(spec, field)


def slice_render_white_light(scene: mi.Scene, spec: SliceSpec, field: object | None = None,
                             light: Spectrum | None = None, progress: bool = False) -> RenderResult:
    """The slab in white light (default: the white LED, ``physics.colour.white_led``), as a photoelastician
    looks at a frozen-stress slice: its fringes at each of the light's wavelengths seen as colour
    (``render.in_white_light``: ``R``, ``G``, ``B``, ``Y`` and ``I.<nm>``)."""
    return Slicer(scene).render_white_light(spec, field, light, progress)


@dataclass(frozen=True)
class SliceLines:
    """The pixels' lines along a normal, from ``starts`` (``far`` beyond the plane through the origin) along
    ``d``; each specimen's inside chords ``(begin, end)`` (K, P) as distances along them."""
    starts: np.ndarray
    d: np.ndarray
    far: float
    inside: tuple       # per specimen shape: (begin, end, medium index + 1)


class Slicer:
    """Slices of one scene. The lines' crossings with the specimens depend only on the normal and the
    resolution, not on the offset, the thickness, the region or the polariscope: they are traced once for
    each (what a viewer's sliders reuse)."""

    def __init__(self, scene: mi.Scene):
        self.scene = scene
        self._lines = {}

    def lines(self, spec: SliceSpec) -> SliceLines:
        key = (spec.plane.normal, spec.resolution)
        if key not in self._lines:
            scene = self.scene
            n = np.asarray(spec.plane.normal)
            low, high = specimen_bounds(specimen_shapes(scene))
            far = float(np.linalg.norm(high - low) + 2 * np.abs(np.concatenate([low, high])).max() + 1.0)
            image = slice_image(scene, Plane(spec.plane.normal, 0.0), spec.resolution)
            starts = image.centres() + far * n
            media = specimen_media(scene)
            inside = tuple(_pairs(occupancy.crossings_along_lines(scene, shape, starts, -n))
                           + (media.index(shape.interior_medium()) + 1,) for shape in specimen_shapes(scene))
            self._lines[key] = SliceLines(starts, -n, far, inside)
        return self._lines[key]

    def render(self, spec: SliceSpec, field: object | None = None,
               lanes: tuple[tuple[str, float], ...] = ()) -> RenderResult:
        """:func:`slice_render` of this scene; with ``lanes`` (``View.lanes``: a channel name and a factor on
        every phase per wavelength), their main channels too, from one spectral march."""
        start = time.perf_counter()
        scene = self.scene
        image = slice_image(scene, spec.plane, spec.resolution)
        require_memory(image.width * image.height * SLICE_BYTES_PER_PIXEL,
                       f"a {image.width}x{image.height} slice", "lower the resolution (mi-nest slice --res)")
        lines = self.lines(spec)
        begin, end, medium = self._slab_chords(spec, lines)
        if not np.isfinite(begin).any():
            raise SliceError(_empty_message(scene, spec))
        integrator = photoelastic_integrator(scene)
        view = View(spec.polariscope, phase_scale(scene, spec.load_scale, spec.wavelength), lanes)
        count = len(lines.starts)
        chords = [(device_array(mi.Float, b), device_array(mi.Float, e), device_array(mi.UInt32, m, np.uint32))
                  for b, e, m in zip(np.where(np.isfinite(begin), begin, 0.0), np.where(np.isfinite(end), end, 0.0),
                                     medium)]
        main, aovs, fringe = integrator.tracer.trace_chords(
            scene, device_array(mi.Point3f, lines.starts.T), device_array(mi.Vector3f, np.tile(lines.d, (count, 1)).T),
            chords, device_array(mi.Vector3f, np.tile(image.right, (count, 1)).T),
            step_size=spec.thickness / STEPS_PER_THICKNESS, field=field, view=view)
        shape = (image.height, image.width)
        channels = {"Y": np.array(main, dtype=np.float32).reshape(shape)}
        for name, value in zip(integrator.aov_names() + list(view.lane_channels), aovs):
            channels[name] = np.array(value, dtype=np.float32).reshape(shape)
        b, c = (np.array(x, dtype=np.float64) for x in fringe)
        # The generator is -(phase) (sin 2 phi, cos 2 phi) in (b, c) for sigma_1 at phi from image right.
        angle = 0.5 * np.degrees(np.arctan2(-b, -c))
        channels["isoclinic.angle"] = np.where(angle <= -90.0, angle + 180.0, angle).astype(np.float32).reshape(shape)
        channels["slab.mask"] = np.isfinite(begin).any(axis=0).astype(np.float32).reshape(shape)
        metadata = {"mi_nest.version": __version__, "mi_nest.slice": spec.describe(),
                    "mi_nest.pixel_mm": f"{image.pixel:.9g}",
                    "mi_nest.extent_mm": ",".join(f"{x:.9g}" for x in image.extent())}
        return RenderResult(channels=channels, seconds=time.perf_counter() - start, metadata=metadata)

    def render_white_light(self, spec: SliceSpec, field: object | None = None, light: Spectrum | None = None,
                           progress: bool = False) -> RenderResult:
        """:func:`slice_render_white_light` of this scene: up to ``LANES_PER_MARCH`` wavelengths per march."""
        if spec.wavelength is not None:
            raise SliceError(f"white light holds every wavelength: leave out the wavelength ({spec.wavelength:g} nm)")
        scene = self.scene

        def in_one_march(wavelengths: list[float]) -> tuple[list[dict[str, np.ndarray]], RenderResult]:
            lanes = tuple((f"lane.{index}", phase_scale(scene, spec.load_scale, w))
                          for index, w in enumerate(wavelengths))
            result = self.render(spec, field, lanes)
            return [{"Y": result.channels[name]} for name, _ in lanes], result

        def one_at_a_time(wavelengths: list[float]) -> tuple[list[dict[str, np.ndarray]], RenderResult]:
            result = self.render(replace(spec, wavelength=wavelengths[0]), field)
            return [{"Y": result.main}], result
        return in_white_light(WavelengthRenders.of(scene, in_one_march, one_at_a_time), light, progress)

    @staticmethod
    def _slab_chords(spec, lines):
        """``(begin, end, medium)`` (K, P): each line's chords inside the slab, a specimen and the region, in
        order away from the camera; ``inf`` pads, ``medium`` is the specimen medium's index plus one."""
        middle = lines.far - spec.plane.offset      # where the lines cross the slab's mid-plane
        count = len(lines.starts)
        slab = (np.full((1, count), middle - 0.5 * spec.thickness), np.full((1, count), middle + 0.5 * spec.thickness))
        region = None if spec.region is None else spec.region.chords(lines.starts, lines.d)
        begins, ends, labels = [], [], []
        for part_begin, part_end, label in lines.inside:
            begin, end = _intersect((part_begin, part_end), slab)
            if region is not None:
                begin, end = _intersect((begin, end), region)
            begins.append(begin)
            ends.append(end)
            labels.append(np.full(begin.shape, label))
        begin, end, medium = _in_order(*(np.concatenate(x) for x in (begins, ends, labels)))
        return begin, end, np.where(np.isfinite(begin), medium, 0)


def _pairs(crossings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Crossings (C, P) of closed surfaces (``inf`` padded) as inside chords ``(begin, end)`` (C/2, P)."""
    ordered = np.sort(crossings, axis=0)
    if len(ordered) % 2:
        ordered = np.concatenate([ordered, np.full((1, ordered.shape[1]), np.inf)])
    return ordered[0::2], ordered[1::2]


def _intersect(a: tuple, b: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Chords in both sets (each disjoint per line), ``inf`` padded, in order."""
    begin = np.maximum(a[0][:, None], b[0][None, :]).reshape(-1, a[0].shape[1])
    end = np.minimum(a[1][:, None], b[1][None, :]).reshape(-1, a[0].shape[1])
    empty = ~(np.isfinite(begin) & (end > begin))
    return _in_order(np.where(empty, np.inf, begin), np.where(empty, np.inf, end))


def _in_order(begin: np.ndarray, *others: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each line's chords (columns) sorted by ``begin``, ``others`` alike, trimmed to the most any line has."""
    order = np.argsort(begin, axis=0, kind="stable")
    kept = max(int(np.isfinite(begin).sum(axis=0).max()), 1)
    return tuple(np.take_along_axis(x, order, axis=0)[:kept] for x in (begin, *others))


def _empty_message(scene, spec):
    along = _bounding_corners(scene) @ np.asarray(spec.plane.normal)
    where = (f"the specimens span {along.min():.4g} to {along.max():.4g} mm along the normal; move the plane "
             "into that range")
    if spec.region is not None:
        where += f" or the region ({spec.region.describe()}) onto the part"
    return f"the {spec.describe()} holds none of the part: {where}"


def _number(text, option):
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise SliceError(f"{option} needs a finite number of mm after '=', got '{text}'")
    return value
