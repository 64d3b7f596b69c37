"""Novel views: the specimen turned to any azimuth and elevation, through any polariscope, as ``mi-nest render``
renders it (one code path: :func:`render_view` is what the command calls); turntables to animated files; a
reconstruction's held-out views beside what its dataset captured there.

Poses follow the datasets' convention (``dataset/schedule.py``): turning the specimen by azimuth about the
scene camera's up axis and by elevation about its right axis, about the specimens' centre, is rendered as
turning the camera the other way, so a view at a held-out rotation's angles is that rotation's camera.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from .. import interrupts
from ..dataset import Dataset
from ..dataset.schedule import Rotation, camera_to_world
from ..io.atomic import atomic_path
from ..physics.polariscope import Polariscope
from ..reconstruct.evaluation import view_psnr
from ..physics.bands import BandSet
from ..physics.colour import Spectrum
from ..render import RenderResult, ViewError, phase_scale, render, render_bands, render_white_light
from ..scene import pose
from ..tracer import View
from .plots import pyplot, save_figure
from .source import ViewSource

ANIMATION_SUFFIXES = (".gif", ".mp4")


def view_pose(source: ViewSource, azimuth: float = 0.0, elevation: float = 0.0) -> np.ndarray:
    """The camera's 4x4 ``to_world`` with the specimen turned by ``azimuth`` and ``elevation`` (degrees)."""
    for name, value in (("azimuth", azimuth), ("elevation", elevation)):
        if not np.isfinite(value):
            raise ValueError(f"--{name} must be a finite number of degrees, got {value}")
    return camera_to_world(source.reference, Rotation(-1, float(azimuth), float(elevation), "view"), source.center)


def render_view(source: ViewSource, azimuth: float = 0.0, elevation: float = 0.0,
                polariscope: Polariscope | None = None, load_scale: float = 1.0, wavelength: float | None = None,
                spp: int | None = None, seed: int = 0, progress: bool = False,
                light: Spectrum | None = None, bands: BandSet | None = None) -> RenderResult:
    """Render ``source`` (its true or reconstructed field) with the specimen turned to ``azimuth``/``elevation``,
    through ``polariscope`` (None: the scene's) at ``load_scale`` times the load and ``wavelength`` (nm), in the
    white ``light`` given (``render.render_white_light``: a colour image) or seen in ``bands``
    (``render.render_bands``: each band's measurements)."""
    result = render_pose(source, view_pose(source, azimuth, elevation), polariscope, load_scale, wavelength, spp,
                         seed, progress, light, bands)
    result.metadata.update({"mi_nest.azimuth": f"{azimuth:g}", "mi_nest.elevation": f"{elevation:g}"})
    return result


def render_pose(source: ViewSource, to_world: np.ndarray, polariscope: Polariscope | None = None,
                load_scale: float = 1.0, wavelength: float | None = None, spp: int | None = None, seed: int = 0,
                progress: bool = False, light: Spectrum | None = None, bands: BandSet | None = None) -> RenderResult:
    """Render ``source`` with its camera at ``to_world`` (4x4), as :func:`render_view` does at its angles: what
    the viewer renders where a drag left the camera."""
    pose(source.scene, to_world)
    if light is not None:
        if wavelength is not None:
            raise ViewError(f"white light holds every wavelength of '{light.name}': leave out the wavelength "
                            f"({wavelength:g} nm)")
        result = render_white_light(source.scene, light, spp, seed, progress, source.field, polariscope, load_scale)
    elif bands is not None:
        result = render_bands(source.scene, bands, spp, seed, progress, source.field, polariscope, load_scale)
    else:
        scale = phase_scale(source.scene, load_scale, wavelength)
        result = render(source.scene, spp=spp, seed=seed, progress=progress, field=source.field,
                        view=View(polariscope, scale))
    result.metadata["mi_nest.source"] = source.name
    return result


def require_animation_path(path: str | Path) -> Path:
    """``path`` if mi_nest can write an animation there: ``.gif``, or ``.mp4`` with the ``video`` extra."""
    path = Path(path)
    if path.suffix.lower() not in ANIMATION_SUFFIXES:
        raise ValueError(f"{path}: a turntable is written as {' or '.join(ANIMATION_SUFFIXES)}; change the suffix")
    if path.suffix.lower() == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ValueError("writing .mp4 needs the video extra (pip install 'mi_nest[video]', which brings "
                             "imageio-ffmpeg and its ffmpeg); or write a .gif") from None
    return path


def turntable(source: ViewSource, frames: int = 36, elevation: float = 0.0, channel: str = "Y",
              polariscope: Polariscope | None = None, load_scale: float = 1.0, wavelength: float | None = None,
              spp: int | None = None, progress: bool = False) -> list[np.ndarray]:
    """``frames`` views a full azimuth turn apart at ``elevation``: the ``channel`` of each (H, W)."""
    if not (isinstance(frames, int) and frames >= 2):
        raise ValueError(f"a turntable needs at least 2 frames, got {frames}")
    from tqdm import tqdm
    images, warned = [], {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for index in tqdm(range(frames), desc="turntable", unit="frame", disable=not progress, leave=False):
            interrupts.check()
            result = render_view(source, 360.0 * index / frames, elevation, polariscope, load_scale, wavelength,
                                 spp, seed=index)
            if channel not in result.channels:
                raise ValueError(f"unknown channel '{channel}'; a render has {list(result.channels)}")
            images.append(result.channels[channel])
            for w in caught:
                warned.setdefault(w.category, []).append(str(w.message))
            caught.clear()
    # Once per kind for the whole turn, not once per frame.
    for category, messages in warned.items():
        warnings.warn(f"{len(messages)} of {frames} frames: {messages[-1]}", category, stacklevel=2)
    return images


def write_animation(path: str | Path, images: list[np.ndarray], fps: float = 12.0,
                    low: float = 0.0, high: float = 1.0) -> Path:
    """The frames as an animated ``.gif`` or ``.mp4``, grey levels linear from ``low`` to ``high``."""
    import imageio.v3 as iio
    path = require_animation_path(path)
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"--fps must be a positive number, got {fps}")
    frames = [np.round(255 * np.clip((image - low) / (high - low), 0, 1)).astype(np.uint8) for image in images]
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, path.suffix) as tmp:
        if path.suffix.lower() == ".gif":
            iio.imwrite(tmp, np.stack(frames), extension=".gif", duration=1000.0 / fps, loop=0)
        else:
            # Even sides for the H.264 encoder's chroma subsampling.
            frames = [np.pad(f, ((0, f.shape[0] % 2), (0, f.shape[1] % 2))) for f in frames]
            iio.imwrite(tmp, np.stack(frames), extension=".mp4", fps=fps)
    return path


def held_out_views(source: ViewSource, count: int = 6, channel: str | None = None,
                   spp: int | None = None) -> list[tuple[dict, np.ndarray, np.ndarray, float]]:
    """Up to ``count`` of the dataset's held-out rotations of a reconstruction: ``(rotation, captured,
    rendered, psnr)``, images of ``channel`` (default: the dataset's first) rendered by :func:`render_view`,
    and the PSNR of all its measurements over the specimen's pixels, as ``mi-nest reconstruct`` reports it (in
    the dataset's bands, for a dataset of several)."""
    if not source.is_reconstruction:
        raise ValueError(f"{source.name} is a scene; held-out views are a reconstruction's: give the output "
                         "directory of mi-nest reconstruct")
    dataset = Dataset(source.reconstruction.source["dataset"])
    channel = channel or dataset.channels[0]
    if channel not in dataset.channels:
        raise ValueError(f"unknown channel '{channel}'; the dataset has {list(dataset.channels)}")
    positions = dataset.split("test")[:count]
    if not positions:
        raise ValueError(f"{dataset.directory} holds no held-out rotations (simulate with --test-fraction > 0)")
    views = []
    for position in positions:
        interrupts.check()
        rotation = dataset.rotations[position]
        rendered = render_view(source, rotation["azimuth"], rotation["elevation"], spp=spp, bands=dataset.bands)
        predicted = np.stack([rendered.channels[name].ravel() for name in dataset.channels], axis=-1)
        ratio = view_psnr(predicted, dataset, position, source.reconstruction.config.optimiser.mask)
        views.append((rotation, dataset.view(position, [channel])[channel], rendered.channels[channel], ratio))
    return views


def write_held_out_sheet(path: str | Path, views: list, title: str) -> Path:
    """Captured above rendered, one column per held-out rotation, with each rotation's PSNR (its 16
    measurements over the specimen's pixels)."""
    plt = pyplot()
    figure, axes = plt.subplots(2, len(views), figsize=(2.6 * len(views), 5.8), squeeze=False,
                                constrained_layout=True)
    for column, (rotation, captured, rendered, ratio) in enumerate(views):
        for row, (image, label) in enumerate(((captured, "captured"), (rendered, "rendered"))):
            axis = axes[row, column]
            axis.imshow(np.clip(image, 0, 1), cmap="gray", vmin=0, vmax=1, interpolation="nearest")
            axis.set_xticks([])
            axis.set_yticks([])
            if column == 0:
                axis.set_ylabel(label)
        axes[0, column].set_title(f"az {rotation['azimuth']:.1f}, el {rotation['elevation']:.1f}\n"
                                  f"PSNR {ratio:.1f} dB", fontsize=9)
    return save_figure(figure, path, title)
