"""The digital twin's camera: a polarisation camera looking at a simulated specimen through imperfect optics.

It renders what the rig would see at the stages' and the waveplate's *true*
positions (read from the simulated devices, never from what was commanded),
through optics with the angle offsets and waveplate retardances that
calibration has to find, and through the dataset camera model (read and shot
noise, quantisation, the IMX250MZR 2x2 micro-polariser mosaic). One capture is
one exposure: the four analyser images 0/45/90/135 at once.

Each pixel integrates ``supersample``^2 point samples of the Jones product:
the intensities, not the Jones matrices, are averaged, as a sensor does. The
Jones images of a rotation are kept, so the waveplate settings of one rotation
render once.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable, Sequence

import numpy as np

from ..dataset.camera import CameraModel
from ..physics.backend import Array
from ..physics.bands import BandSet
from ..physics.polariscope import ANALYZERS, Polariscope, standard_polariscope
from ..physics.su2 import identity

# A Jones quaternion ``(a, b, c, d)`` of every point sample in view.
Jones = Sequence[Array]
# ``jones_of(azimuth, elevation)``: the point samples' Jones quaternions at each wavelength a colour camera's bands
# weigh (one: a monochrome camera, or the same at every wavelength) and the samples per pixel along each axis.
JonesOf = Callable[[float, float], tuple[Sequence[Jones], int]]


@dataclass(frozen=True)
class Optics:
    """The polariscope as built: angle offsets (degrees, from the nominal), waveplate retardances, and
    the faults of angle sense that free-space captures cannot see (docs/rig.md, "Angle sense and handedness").

    ``polarizer`` is the reference of every angle (the light panel's LP1 at
    90 degrees defines the frame), so it has no offset of its own. Angles turn
    from image right towards image up (counter-clockwise looking toward the
    source). ``mirrored``: every mount and the camera turn the other way, so
    each physical angle is the negative of what the mount reading plus its
    offset says. ``qwp1_swapped``/``qwp2_swapped``: the plate's mark is on its
    slow axis, so its fast axis sits 90 degrees from the mark.
    """
    analyzer_offset: float = 0.0     # the camera's micro-polarisers against the image axes
    qwp1_offset: float = 0.0         # QWP1 (manual mount) against its scale
    qwp2_offset: float = 0.0         # QWP2's fast axis against the ELL14's zero
    qwp1_retardance: float = 90.0
    qwp2_retardance: float = 90.0
    mirrored: bool = False
    qwp1_swapped: bool = False
    qwp2_swapped: bool = False

    def __post_init__(self) -> None:
        for name in ("mirrored", "qwp1_swapped", "qwp2_swapped"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name} must be true or false, got {getattr(self, name)!r}")

    def polariscope(self, qwp1: float, qwp2: float, analyzer: float, polarizer: float = 90.0) -> Polariscope:
        """The physical polariscope when the mounts read ``qwp1``, ``qwp2`` and the analyser is ``analyzer``."""
        sense = -1.0 if self.mirrored else 1.0
        return standard_polariscope(sense * polarizer,
                                    sense * (qwp1 + self.qwp1_offset + 90.0 * self.qwp1_swapped),
                                    sense * (qwp2 + self.qwp2_offset + 90.0 * self.qwp2_swapped),
                                    sense * (analyzer + self.analyzer_offset), self.qwp1_retardance,
                                    self.qwp2_retardance)

    def to_dict(self) -> dict[str, float | bool]:
        return asdict(self)


class SimulatedCamera:
    """Captures of ``scene`` (None: free space) posed by ``pose_of(azimuth, elevation) -> to_world``.

    ``rig_state()`` returns the true ``(azimuth, elevation, qwp2)`` in degrees;
    ``qwp1`` is the manual plate's setting, changed by the operator (or a test).
    A colour camera (``bands``, ``physics.bands``) sees each band through its
    colour filter: its images are ``(bands, H, W)``.
    """

    def __init__(self, jones_of: JonesOf, rig_state: Callable[[], tuple[float, float, float]],
                 optics: Optics = Optics(), camera: CameraModel = CameraModel(), resolution: tuple[int, int] = (64, 64),
                 bands: BandSet | None = None) -> None:
        self.jones_of = jones_of
        self.rig_state = rig_state
        self.optics = optics
        self.camera = camera
        self.resolution = tuple(resolution)
        self.bands = bands
        self.qwp1 = 45.0
        self.exposures = 0
        self._cached = None

    def show(self, jones_of: JonesOf) -> None:
        """Put another object in view (``jones_of`` as in the constructor)."""
        self.jones_of = jones_of
        self._cached = None

    def _jones(self, azimuth, elevation):
        key = (round(azimuth, 6), round(elevation, 6))
        if self._cached is None or self._cached[0] != key:
            self._cached = (key, self.jones_of(azimuth, elevation))
        return self._cached[1]

    def capture(self) -> dict[int, np.ndarray]:
        """``{analyser: (H, W) float32}`` normalised intensities of one exposure at the rig's true state
        (``(bands, H, W)`` for a colour camera)."""
        azimuth, elevation, qwp2 = self.rig_state()
        jones, factor = self._jones(azimuth, elevation)
        ideal = analyser_images(self.optics, self.qwp1, qwp2, jones, factor, self.resolution, self.bands)
        if self.bands is None:
            captured = self.camera.capture({f"analyzer.{a}": image for a, image in ideal.items()}, self.exposures)
            images = {int(name.split(".")[1]): image for name, image in captured.items()}
        else:
            captured = self.camera.capture({f"{band}.analyzer.{a}": image[k] for a, image in ideal.items()
                                            for k, band in enumerate(self.bands.names)}, self.exposures, self.bands)
            images = {a: np.stack([captured[f"{band}.analyzer.{a}"] for band in self.bands.names]) for a in ideal}
        self.exposures += 1
        return images


def analyser_images(optics: Optics, qwp1: float, qwp2: float, jones: Sequence[Jones], factor: int,
                    resolution: tuple[int, int], bands: BandSet | None = None) -> dict[int, np.ndarray]:
    """``{analyser: (H, W)}`` pixel means of what ``optics`` with its mounts at ``qwp1`` and ``qwp2`` pass of
    ``jones`` (a :data:`JonesOf`'s, at the bands' wavelengths); for ``bands``, ``(bands, H, W)``: each band's
    weighted sum over its wavelengths (the polariscope's elements achromatic, as every render takes them)."""
    images = {}
    for analyzer in ANALYZERS:
        scope = optics.polariscope(qwp1, qwp2, analyzer)
        per_wavelength = np.stack([pixel_means(scope.intensity(q), factor, resolution) for q in jones])
        if bands is None:
            images[analyzer] = per_wavelength[0]
        elif len(jones) == 1:       # the same at every wavelength (free space): each band's weights sum to 1
            images[analyzer] = np.repeat(per_wavelength, len(bands), axis=0)
        else:
            images[analyzer] = bands.combine(per_wavelength)
    return images


def pixel_means(samples: Array, factor: int, resolution: tuple[int, int]) -> np.ndarray:
    """``(H, W)`` means of ``factor`` x ``factor`` point samples per pixel (a scalar: the same everywhere)."""
    width, height = resolution
    samples = np.broadcast_to(samples, (height * factor, width * factor))
    return samples.reshape(height, factor, width, factor).mean(axis=(1, 3))


def free_space(azimuth: float, elevation: float) -> tuple[Sequence[Jones], int]:
    """No specimen: the identity everywhere and at every wavelength (the calibration captures)."""
    return (identity(np.float64(0.0)),), 1


def scene_renderer(scene_file: str, defines: dict, resolution: tuple[int, int], supersample: int = 2,
                   spp: int = 1, bands: BandSet | None = None) -> JonesOf:
    """``jones_of(azimuth, elevation)`` rendering ``scene_file`` at ``supersample`` times ``resolution``: the
    per-sample Jones quaternions ``(a, b, c, d)`` of shape ``(H * s, W * s)`` and the factor ``s``, at the
    scene's wavelength, or at each of ``bands``' (one spectral march per 16 wavelengths)."""
    from ..dataset.schedule import Rotation, camera_to_world
    from ..render import jones_at_wavelengths, render
    from ..scene import load_scene, pose, reference_pose, specimen_bounds, specimen_shapes

    width, _ = resolution
    scene = load_scene(scene_file, **{**dict(defines), "res": width * supersample, "spp": spp})
    reference = reference_pose(scene)
    shapes = specimen_shapes(scene)
    low, high = specimen_bounds(shapes)
    center = 0.5 * (low + high)

    def jones_of(azimuth: float, elevation: float) -> tuple[Sequence[Jones], int]:
        pose(scene, camera_to_world(reference, Rotation(0, azimuth, elevation, "train"), center))
        if bands is None:
            channels = render(scene).channels
            jones = [tuple(channels[f"jones.{k}"] for k in "abcd")]
        else:
            jones = jones_at_wavelengths(scene, bands.wavelengths)
        return [tuple(x.astype(np.float64) for x in q) for q in jones], supersample

    return jones_of
