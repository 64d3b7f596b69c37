"""The integrator's channels and how they reach the film.

For box-filtered films without border every sample lands in its own pixel, so
the integrator sums each pixel's samples itself (:func:`develop_pixel_sums`)
instead of splatting them one atomic add at a time through
``ADIntegrator.render``. On monochrome HDR films the render kernel also writes
the developed image, and the film receives its pixel sums as a lazy expression
of that image, evaluated only if the film is read. Every path gives the same
image, and the film holds it afterwards.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_nest.physics import MEASUREMENTS

JONES_CHANNELS = ("jones.a", "jones.b", "jones.c", "jones.d")
CHARACTERISTIC_CHANNELS = ("char.delta", "char.theta", "char.gamma")
# Unwrapped fringe order of the linear model, |sum of the step generators| / pi: exact
# where the axes do not turn along the ray, and what the aliasing guard differentiates.
FRINGE_CHANNELS = ("fringe.order",)
# Total length (mm) of each ray's path inside specimens: a thickness map.
PATH_CHANNELS = ("path.length",)
CHANNELS = JONES_CHANNELS + CHARACTERISTIC_CHANNELS + tuple(MEASUREMENTS) + FRINGE_CHANNELS + PATH_CHANNELS
# Channels whose derivative ``render_backward`` does not propagate: the fringe-order estimate
# and the path length are diagnostics, not functions of the Jones product.
UNDIFFERENTIATED = FRINGE_CHANNELS + PATH_CHANNELS
# What the aliasing guard reads.
GUARDED_CHANNELS = FRINGE_CHANNELS + PATH_CHANNELS


def sums_pixels_directly(film: mi.Film) -> bool:
    """A box-filtered film without border receives each sample in its own pixel only."""
    return film.rfilter().is_box_filter() and not film.sample_border() and \
        film.rfilter().border_size() == 0


def develops_directly(film: mi.Film) -> bool:
    """Whether the integrator writes ``film.develop()``'s image itself: a monochrome HDR film,
    whose image is luminance (and alpha) then the AOVs, each pixel's sum over its weight."""
    return film.class_name() == "HDRFilm" and mi.is_monochromatic


def channel_names(film: mi.Film, lanes: tuple[str, ...] = ()) -> list[str]:
    """Names of the channels of the image a render onto ``film`` returns, in order; ``lanes``: a spectral
    render's wavelengths' channels, after :data:`CHANNELS`."""
    if sums_pixels_directly(film) and develops_directly(film):
        alpha = ["A"] if mi.has_flag(film.flags(), mi.FilmFlags.Alpha) else []
        return ["Y"] + alpha + list(CHANNELS) + list(lanes)
    return [str(f.name) for f in film.bitmap().struct_()]


def guarded_channels(image: mi.TensorXf, lanes: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The fringe order and path length of a developed image (``lanes`` spectral channels after the AOVs), as
    ``(H, W)`` host arrays."""
    pixels = image.numpy()      # shares the evaluated image's memory on the LLVM backend
    return tuple(pixels[..., i] for i in _guarded_positions(image.shape[-1], lanes))


def develop_pixel_sums(film: mi.Film, spp: int, value: mi.Float,
                       aovs: list[mi.Float]) -> tuple[mi.TensorXf, tuple[np.ndarray, np.ndarray]]:
    """The developed image of per-sample ``value`` and ``aovs`` (``spp`` consecutive samples per pixel; the
    :data:`CHANNELS`, then a spectral render's lanes), left in ``film``.

    Returns the image and, for the aliasing guard, its fringe order and path
    length as contiguous ``(H, W)`` host arrays: read from the interleaved
    image, every value would cost a cache line.
    """
    # The channel layout of ADIntegrator._splat_to_block: colour, alpha, weight, AOVs.
    one = dr.full(mi.Float, 1.0, dr.width(value))
    alpha = mi.has_flag(film.flags(), mi.FilmFlags.Alpha)
    channels = [value, value, value] + ([one] if alpha else [])
    channels += [one] + aovs
    sums = _pixel_sums(spp, channels)
    lanes = len(aovs) - len(CHANNELS)
    guarded = [sums[i] for i in _guarded_positions(len(sums), lanes)]
    width, height = film.crop_size()
    if develops_directly(film):
        # What film.develop() would return, written by the march's own kernel: the film's put,
        # conversion and normalisation passes over the image cost 7% of a 256-step 256^2 render.
        developed = sums[:1] + sums[3:4 if alpha else 3] + sums[len(sums) - len(aovs):]
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


def _guarded_positions(count, lanes):
    """Where the aliasing guard's channels sit among ``count`` channels that end with the AOVs, then ``lanes``
    spectral channels."""
    return [count - lanes - len(CHANNELS) + CHANNELS.index(name) for name in GUARDED_CHANNELS]


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
