"""Render a photoelastic scene to named channels, in passes with a progress bar."""
from __future__ import annotations

import math
import os
import resource
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import mitsuba as mi
import numpy as np

from . import interrupts
from .arguments import whole_number
from .fields import StressField
from .physics.aliasing import FringeAliasing, beat_factor
from .physics import MEASUREMENTS
from .physics.bands import BandSet
from .physics.colour import Spectrum
from .physics.polariscope import Polariscope
from .scene import (SceneError, load_scene, photoelastic_integrator, polariscope_camera, polariscope_light,
                    scene_sensor, specimen_media)
from .tracer import SCENE_VIEW, LaneChannels, View
from .tracer.film import GUARDED_CHANNELS, JONES_CHANNELS
from .version import __version__

# Largest fringe order a render keeps. A uniform 6 mm slab renders within 7e-4 of its closed form up to
# 5.6e4 orders and 0.08 to 0.26 off at 5.6e5 (float32 phases); real specimens show a few hundred.
MAX_FRINGE_ORDER = 1e5


class NonFiniteImageError(SceneError):
    """A render produced NaN or inf pixels."""


def _check_image(scene, image, names, passes):
    """Refuse an image with NaN or inf pixels, naming the likely cause; warn when no pixel sees a specimen.

    ``image`` (H, W, C) is the sum of ``passes`` passes, its channels named by ``names``.
    """
    name = scene.id() or "the scene"
    length = image[..., names.index("path.length")]
    order = np.abs(image[..., names.index("fringe.order")]) / passes
    bad = ~np.isfinite(image)
    if bad.any():
        finite = np.isfinite(order)
        extent = (f"fringe orders reach {order[finite].max():.3g} (real parts show a few hundred at most)"
                  if finite.any() else "the fringe order overflows")
        channels = [n for n, b in zip(names, bad.any(axis=(0, 1))) if b]
        raise NonFiniteImageError(f"{name}: {int(bad.any(axis=-1).sum())} of {length.size} pixels are NaN or inf "
                                  f"(in {', '.join(channels[:3])}{', ...' if len(channels) > 3 else ''}): the stress "
                                  f"field is NaN there, or so large that {extent}; check its magnitude and units "
                                  "(MPa)")
    if order.max() > MAX_FRINGE_ORDER:
        raise SceneError(f"{name}: fringe orders reach {order.max():.3g} in {int((order > MAX_FRINGE_ORDER).sum())} of "
                         f"{length.size} pixels; beyond {MAX_FRINGE_ORDER:.0e} the float32 phases lose their meaning "
                         "(real parts show a few hundred at most): check the stress magnitude and units (MPa) and "
                         "the stress-optic coefficient (Brewster)")
    if not (length > 0).any():
        warnings.warn(f"{name}: the camera sees no specimen (path.length is 0 in every pixel), so the image is the "
                      "empty polariscope's; check the camera pose (origin, target, to_world) and the specimen's "
                      "position, size and units (mm)", RuntimeWarning, stacklevel=3)


@dataclass
class RenderResult:
    """Named ``(H, W)`` float32 channels; ``Y`` is the scene's own polariscope."""
    channels: dict
    seconds: float
    metadata: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)  # what the integrator warned about, once each
    aliasing: FringeAliasing | None = None          # the aliasing guard's report on the last pass
    beat: FringeAliasing | None = None              # a render of bands: the same on their slowest beat

    @property
    def main(self) -> np.ndarray:
        return self.channels["Y"]

    def write_exr(self, path: str | Path) -> None:
        from .io.exr import write_channels
        write_channels(path, self.channels, metadata=self.metadata)

    def write_png(self, path: str | Path, channel: str | None = None) -> None:
        """A PNG of ``channel``; by default the main channel, or the colour image of a white-light render."""
        from .io.preview import write_colour_preview, write_preview
        if channel is None and all(c in self.channels for c in COLOUR_CHANNELS):
            write_colour_preview(path, np.stack([self.channels[c] for c in COLOUR_CHANNELS], axis=-1))
        else:
            write_preview(path, self.channels[channel or "Y"])

    def write(self, output: str | Path, png: str | Path | None = None) -> None:
        """Write the EXR (and a PNG of the main channel) and say where."""
        self.write_exr(output)
        print(f"wrote {Path(output).resolve()} ({len(self.channels)} channels, {self.main.shape[1]}x"
              f"{self.main.shape[0]}, {self.seconds:.2f} s)")
        if png:
            self.write_png(png)
            print(f"wrote {Path(png).resolve()}")


def render(scene: mi.Scene | str | Path, spp: int | None = None, seed: int = 0, passes: int | None = None,
           progress: bool = False, field: StressField | None = None, view: View = SCENE_VIEW) -> RenderResult:
    """Render ``scene`` (a loaded scene, or a scene file or shipped scene name, loaded with its defaults) and
    return its named channels.

    The samples are split into ``passes`` kernel launches of equal size (default:
    up to 16) so that ``progress=True`` can show a bar; every pass uses its own seed
    and the passes are averaged, which is exact for box-filtered films. ``field``,
    if given, is rendered in every specimen instead of its own stress (a
    reconstruction's field). ``view`` shows the specimens through another
    polariscope and scales every phase (:func:`phase_scale`).
    """
    if isinstance(scene, (str, Path)):
        scene = load_scene(scene)
    if not isinstance(scene, mi.Scene):
        raise TypeError(f"'scene' must be a scene (mi_nest.load_scene(...)) or a scene file or shipped scene name, "
                        f"got {scene!r:.60} ({type(scene).__name__})")
    if field is not None and not isinstance(field, StressField):
        raise TypeError(f"'field' must be a StressField (a reconstruction's .field, or one of mi_nest.fields) to "
                        f"render in every specimen, or None for their own stress; got {field!r:.60} "
                        f"({type(field).__name__})")
    sensor = scene_sensor(scene)
    film = sensor.film()
    integrator = scene.integrator()
    spp, passes = render_plan(scene, spp, passes)
    seed = whole_number("seed", seed, minimum=0)
    from tqdm import tqdm
    start = time.perf_counter()
    total = None
    # Every pass checks the same things (aliasing, rk4 norm): report each kind once, the last pass's. The bar
    # opens last, so a Ctrl-C while the scene is set up leaves no half-drawn bar before its one line.
    with warnings.catch_warnings(record=True) as caught, interrupts.deferred(), \
            tqdm(total=passes, desc="render", unit="pass", leave=False, disable=not progress) as bar:
        warnings.simplefilter("always")
        decision = integrator.decide(scene, sensor, field, view)     # once for every pass
        for index in range(passes):
            interrupts.check()
            image, aliasing = integrator.render_with_aliasing(scene, sensor, seed * passes + index, spp // passes,
                                                              field, view, decision)
            image = image.numpy()
            total = image if total is None else total + image
            bar.update()
    # Before the integrator's warnings are repeated: an image refused for NaN pixels needs no warning about them.
    names = integrator.channel_names(film, view)
    _check_image(scene, total, names, passes)
    said = _warn_once_each(caught)
    seconds = time.perf_counter() - start
    if passes > 1:
        total /= passes
    if len(names) != total.shape[-1]:
        raise SceneError(f"film produced {total.shape[-1]} channels but names {names}")
    # Views into the (H, W, C) image: a transposing copy costs more than the render.
    channels = {name: total[..., index] for index, name in enumerate(names)}
    metadata = {"mi_nest.version": __version__, "mi_nest.spp": spp,
                "mi_nest.integrator": integrator.class_name()}
    return RenderResult(channels=channels, seconds=seconds, metadata=metadata, warnings=said, aliasing=aliasing)


def _warn_once_each(caught: list[warnings.WarningMessage]) -> list[str]:
    """Warn again the last of each kind of ``caught`` warnings (every pass or wavelength warns alike), and
    return their messages."""
    last_of_kind = {(w.category, w.filename, w.lineno): w for w in caught}
    for w in last_of_kind.values():
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return [str(w.message) for w in last_of_kind.values()]


# A white-light render's colour image: sRGB, display-encoded, white-balanced to the light.
COLOUR_CHANNELS = ("R", "G", "B")


def white_light() -> Spectrum:
    """The light white-light renders and slices use unless given another: the white LED panel
    (``physics.colour.white_led``) every ``WHITE_LIGHT_STEP`` nm."""
    from .physics.colour import LIGHTS
    return LIGHTS["white_led"]()


def scene_light(scene: mi.Scene) -> Spectrum | None:
    """The light panel's spectrum (``polariscope_light``'s ``spectrum``); None: one wavelength, the media's."""
    return polariscope_light(scene).spectrum


def scene_bands(scene: mi.Scene) -> BandSet | None:
    """The camera's colour bands (``polariscope``'s ``bands``) under the panel's light (the white LED when the
    panel names none); None for a monochrome camera."""
    from .physics.bands import parse_bands
    text = polariscope_camera(scene).bands
    return None if text is None else parse_bands(text, scene_light(scene))


def render_white_light(scene: mi.Scene, light: Spectrum | None = None, spp: int | None = None, seed: int = 0,
                       progress: bool = False, field: StressField | None = None,
                       polariscope: Polariscope | None = None, load_scale: float = 1.0) -> RenderResult:
    """``scene`` seen in white light (default: the white LED panel, ``physics.colour.white_led``): the main
    channel at each of the light's wavelengths (:func:`render_wavelengths`) seen as colour
    (:func:`in_white_light`)."""
    light = white_light() if light is None else light
    return in_white_light(render_wavelengths(scene, light.wavelengths, spp, seed, field, polariscope, load_scale),
                          light, progress)


def render_bands(scene: mi.Scene, bands: BandSet, spp: int | None = None, seed: int = 0, progress: bool = False,
                 field: StressField | None = None, polariscope: Polariscope | None = None,
                 load_scale: float = 1.0) -> RenderResult:
    """``scene`` seen by a camera with ``bands`` (``physics.bands``: an RGB sensor under a white light, or narrow
    bands): each band's main channel and 16 measurements as ``<band>`` and ``<band>.<measurement>``, the weighted
    sums of its wavelengths' renders (:func:`render_wavelengths`). ``path.length``, ``fringe.order`` and the
    aliasing report are the shortest wavelength's (the densest fringes), ``beat`` that report on the slowest beat
    between two bands (:func:`~mi_nest.physics.aliasing.beat_factor`); ``Y`` is the first band's."""
    renders = render_wavelengths(scene, bands.wavelengths, spp, seed, field, polariscope, load_scale,
                                 LaneChannels.MEASUREMENTS)
    images, first, last, said, seconds = _wavelength_images(renders, bands.wavelengths, progress, "bands")
    names = ("Y",) + tuple(MEASUREMENTS)
    channels = {name: first.channels[name] for name in GUARDED_CHANNELS}
    for band, combined in zip(bands.names, bands.combine([[image[n] for n in names] for image in images])):
        channels.update({band if n == "Y" else f"{band}.{n}": c.astype(np.float32) for n, c in zip(names, combined)})
    channels["Y"] = channels[bands.names[0]]
    metadata = {**last.metadata, "mi_nest.bands": bands.describe()}
    scales = [phase_scale(scene, load_scale, w) for w in bands.wavelengths]
    factor = beat_factor(bands.weights @ scales, scales[0])
    beat = None if factor is None or first.aliasing is None else first.aliasing.scaled(factor)
    return RenderResult(channels=channels, seconds=seconds, metadata=metadata, warnings=said, aliasing=first.aliasing,
                        beat=beat)


def jones_at_wavelengths(scene: mi.Scene, wavelengths, spp: int | None = None,
                         seed: int = 0) -> list[tuple[np.ndarray, ...]]:
    """Each wavelength's Jones product ``(jones.a, jones.b, jones.c, jones.d)`` images of ``scene`` (its pixel
    means), from :func:`render_wavelengths`: what a polariscope as built (the rig's twin) is applied to."""
    renders = render_wavelengths(scene, wavelengths, spp, seed, outputs=LaneChannels.JONES)
    images = _wavelength_images(renders, wavelengths, False, "Jones")[0]
    return [tuple(image[name] for name in JONES_CHANNELS) for image in images]


def wavelength_channel(wavelength: float) -> str:
    """The channel of a white-light render that holds one wavelength's image."""
    return f"I.{wavelength:g}"


# Most wavelengths one march carries: per wavelength, 16 lanes cost as little as 8 or less
# (benchmarks/spectral.py, docs/physics.md section 9); more compile longer.
LANES_PER_MARCH = 16


@dataclass(frozen=True)
class WavelengthRenders:
    """What renders a scene (or a slice) at a group of up to ``per_call`` wavelengths: ``render(wavelengths)``
    gives one image dict per wavelength (its main channel as ``Y``) and the call's :class:`RenderResult`."""
    render: Callable[[list[float]], tuple[list[dict[str, np.ndarray]], RenderResult]]
    per_call: int = 1

    @classmethod
    def of(cls, scene: mi.Scene, in_one_march: Callable, one_at_a_time: Callable) -> WavelengthRenders:
        """``in_one_march`` (up to :data:`LANES_PER_MARCH` wavelengths a call) where ``scene``'s method marches
        several wavelengths at once (``tracer/spectral.py``), else ``one_at_a_time``."""
        if photoelastic_integrator(scene).tracer.has_spectral_march():
            return cls(in_one_march, LANES_PER_MARCH)
        return cls(one_at_a_time)


def render_wavelengths(scene: mi.Scene, wavelengths, spp: int | None = None, seed: int = 0,
                       field: StressField | None = None, polariscope: Polariscope | None = None,
                       load_scale: float = 1.0, outputs: LaneChannels = LaneChannels.INTENSITY) -> WavelengthRenders:
    """What renders ``scene`` at some of ``wavelengths``: each one's main channel as ``Y`` and its ``outputs``
    (none, its 16 measurements, or its Jones product ``jones.a`` ...), every phase scaled by
    ``C(lambda) / lambda`` (:func:`phase_scale`, the media's dispersion) with the polariscope's elements taken as
    achromatic, the same samples at every wavelength (one seed). Up to :data:`LANES_PER_MARCH` wavelengths share
    each march (``tracer/spectral.py``: the stress looked up once for all, refracted paths followed once for all);
    with ``rk4``, one render each."""
    names = outputs.value

    def in_one_march(group: list[float]) -> tuple[list[dict[str, np.ndarray]], RenderResult]:
        lanes = tuple((f"lane.{index}", phase_scale(scene, load_scale, w)) for index, w in enumerate(group))
        result = render(scene, spp=spp, seed=seed, field=field,
                        view=View(polariscope, 1.0, lanes, outputs))
        return [{"Y": result.channels[lane], **{n: result.channels[f"{lane}.{n}"] for n in names}}
                for lane, _ in lanes], result

    def one_at_a_time(group: list[float]) -> tuple[list[dict[str, np.ndarray]], RenderResult]:
        result = render(scene, spp=spp, seed=seed, field=field,
                        view=View(polariscope, phase_scale(scene, load_scale, group[0])))
        return [{n: result.channels[n] for n in ("Y",) + names}], result

    return WavelengthRenders.of(scene, in_one_march, one_at_a_time)


def in_white_light(renders: WavelengthRenders, light: Spectrum | None = None, progress: bool = False) -> RenderResult:
    """The images ``renders`` makes at each of ``light``'s wavelengths (default: :func:`white_light`; a
    :func:`render_wavelengths`, or a slice's), their main channels seen together as colour
    (``physics.colour``): channels ``R``, ``G``, ``B`` (sRGB), ``Y`` (the luminance, 1 for the light passed whole)
    and each wavelength's image as ``I.<nm>``."""
    from .physics.colour import to_srgb, tristimulus
    light = white_light() if light is None else light
    images, _, last, said, seconds = _wavelength_images(renders, light.wavelengths, progress, "white light")
    bands = [image["Y"] for image in images]
    spectrum = np.stack(bands, axis=-1).astype(np.float64)
    channels = dict(zip(COLOUR_CHANNELS, np.moveaxis(to_srgb(spectrum, light).astype(np.float32), -1, 0)))
    channels["Y"] = tristimulus(spectrum, light)[..., 1].astype(np.float32)
    channels.update({wavelength_channel(wavelength): band for wavelength, band in zip(light.wavelengths, bands)})
    metadata = {**last.metadata, "mi_nest.light": light.name,
                "mi_nest.wavelengths": ",".join(f"{w:g}" for w in light.wavelengths)}
    return RenderResult(channels=channels, seconds=seconds, metadata=metadata, warnings=said)


def _wavelength_images(renders: WavelengthRenders, wavelengths, progress: bool, description: str):
    """``(images per wavelength, the first call's result, the last call's, the warnings said, seconds)``.

    ``renders`` takes up to ``per_call`` wavelengths at a time, always as many: the last group is padded with
    its last wavelength (whose image is dropped), so that every call launches the same kernel. Every call
    warns alike (aliasing): each kind is said once, the last call's.
    """
    from tqdm import tqdm
    wavelengths = [float(w) for w in wavelengths]
    size = math.ceil(len(wavelengths) / math.ceil(len(wavelengths) / renders.per_call))
    start = time.perf_counter()
    images, results = [], []
    with warnings.catch_warnings(record=True) as caught, \
            tqdm(total=len(wavelengths), desc=description, unit="wavelength", leave=False,
                 disable=not progress) as bar:
        warnings.simplefilter("always")
        for first in range(0, len(wavelengths), size):
            group = wavelengths[first:first + size]
            group_images, result = renders.render(group + group[-1:] * (size - len(group)))
            images += group_images[:len(group)]
            results.append(result)
            bar.update(len(group))
    said = _warn_once_each(caught)
    return images, results[0], results[-1], said, time.perf_counter() - start


# Bytes per sample beyond its channels during a pass (ray, loop state). With it the estimate below stayed
# above the measured peak of every render of the disk from 512x512 to 2048x2048 at 1 to 4 samples per pass.
SAMPLE_STATE_BYTES = 64


def render_plan(scene: mi.Scene, spp: int | None = None, passes: int | None = None) -> tuple[int, int]:
    """``(spp, passes)`` of a :func:`render` of ``scene``, checked: a photoelastic integrator, whole numbers,
    and an image that is not empty and fits in the memory this process may allocate."""
    sensor = scene_sensor(scene)
    integrator = photoelastic_integrator(scene)
    spp = whole_number("spp", sensor.sampler().sample_count() if spp is None else spp)
    if passes is None:
        passes = max(p for p in range(1, min(spp, 16) + 1) if spp % p == 0)
    passes = whole_number("passes", passes)
    if spp % passes:
        raise SceneError(f"spp={spp} cannot be split into {passes} equal passes")
    _check_image_size(sensor.film(), len(integrator.aov_names()) + 2, spp // passes, passes)
    return spp, passes


def _check_image_size(film, channels, samples_per_pass, passes):
    """Refuse an empty film, or a render that needs more memory than this process may allocate."""
    width, height = (int(n) for n in film.size())
    if width < 1 or height < 1:
        raise SceneError(f"the film is {width}x{height} pixels; give it a width and height of at least 1 "
                         "(the shipped scenes' $res)")
    pixels = width * height
    images = 1 if passes == 1 else 3        # a single pass's image is the result; more passes add a sum
    require_memory(pixels * channels * 4 * images + pixels * samples_per_pass * (channels * 4 + SAMPLE_STATE_BYTES),
                   f"a {width}x{height} render of {channels} channels at {samples_per_pass} sample(s) per pixel per "
                   "pass", "lower the resolution or the samples per pixel (spp)")


def require_memory(needed: float, work: str, smaller: str) -> None:
    """Refuse ``work`` (what needs the memory, for the message) when its ``needed`` bytes exceed what this
    process may allocate, before it starts; ``smaller`` says how to make it smaller. Renders, exports, slices
    and training batches are refused so."""
    available = available_memory()
    if available is not None and needed > available:
        raise ValueError(f"{work} needs about {needed / 2**30:.3g} GiB; {available / 2**30:.3g} GiB are available: "
                         f"{smaller}")


def available_memory() -> int | None:
    """Bytes this process may still allocate: the least of the machine's available memory, its cgroup's
    limit and its address-space limit (None where none can be read)."""
    limits = []
    meminfo = _read_numbers("/proc/meminfo", "MemAvailable:")
    if meminfo is not None:
        limits.append(meminfo * 1024)
    cgroup_limit = _read_numbers("/sys/fs/cgroup/memory.max")
    cgroup_used = _read_numbers("/sys/fs/cgroup/memory.current")
    if cgroup_limit is not None and cgroup_used is not None:
        limits.append(cgroup_limit - cgroup_used)
    address_space = resource.getrlimit(resource.RLIMIT_AS)[0]
    mapped = _read_numbers("/proc/self/statm")
    if address_space != resource.RLIM_INFINITY and mapped is not None:
        limits.append(address_space - mapped * os.sysconf("SC_PAGE_SIZE"))
    return max(0, min(limits)) if limits else None


def _read_numbers(path, key=None):
    """The first number of a /proc or /sys file (of its line starting with ``key``); None if there is none."""
    try:
        with open(path) as handle:
            for line in handle:
                if key is None or line.startswith(key):
                    return int(line.split()[1 if key else 0])
    except (OSError, ValueError, IndexError):   # no such file, or "max" (no limit)
        return None
    return None


class ViewError(ValueError):
    """A view's light or load that no render can take."""


def phase_scale(scene: mi.Scene, load_scale: float = 1.0, wavelength: float | None = None) -> float:
    """The factor on every phase of a view at ``load_scale`` times the load and at ``wavelength`` (nm; None:
    the material's): the phase goes as ``C(lambda) / lambda``, C following the medium's dispersion (constant
    unless the scene gives one, docs/physics.md section 9)."""
    check_light_and_load(load_scale, wavelength)
    if wavelength is None:
        return float(load_scale)
    try:
        # Each medium's phase per mm goes as C(lambda) / lambda: its own wavelength over this one, times its
        # dispersion (1.0 for a constant C, so the factor is what it was before dispersion existed).
        scales = {float(load_scale) * medium.wavelength / wavelength * medium.dispersion_factor(wavelength)
                  for medium in specimen_media(scene)}
    except ValueError as error:
        raise ViewError(str(error)) from None
    if len(scales) > 1:
        raise ViewError(f"at {wavelength:g} nm the specimens' media change their phases by different factors "
                        f"({', '.join(f'{s:.4g}' for s in sorted(scales))}: their wavelengths or dispersions "
                        "differ); leave the wavelength at the media's own")
    return scales.pop()


def check_light_and_load(load_scale: float, wavelength: float | None) -> None:
    """Refuse a load scale that is not finite, or a wavelength that is not a positive number of nm."""
    if not math.isfinite(load_scale):
        raise ViewError(f"the load scale must be a finite number, got {load_scale}")
    if wavelength is not None and not (math.isfinite(wavelength) and wavelength > 0):
        raise ViewError(f"the wavelength must be a positive number of nm, got {wavelength}")
