"""The rig's handedness, checked on a specimen of known stress: what free-space calibration cannot see.

With nothing in view (Jones = identity) the intensities do not change when
every angle of the optics turns the other way (``Optics.mirrored``: mounts and
camera read in the opposite sense) or when both waveplates are conjugated
(their fast and slow axes swapped, which is the same as the stress sign
reversed), so ``calibration.fit`` finds the same optics for those rigs as for
the rig as built, and a single swapped waveplate only up to which one. A
specimen whose stress is known in sign and principal directions tells them
apart: mirroring turns its isoclinics the other way, conjugation reverses its
retardance in half of the 16 measurements. It must be neither mirror-symmetric
nor unchanged by a sign flip: a rig that is the mirror image of the model as a
whole (its camera image flipped and every angle reversed with it) shows a
mirror-symmetric specimen just as the rig as built would, while an oblique one
then matches no hypothesis. The default is the disk in diametral compression
with its load axis 30 degrees counter-clockwise from image up.

After the free-space sweep the stages go home, the operator puts the specimen
in view and the rig captures QWP1 x QWP2 x analyser (16 measurements) at that
pose. The captures are compared, inside the specimen, with the calibrated
model's predictions under the four hypotheses of :func:`hypotheses`: the
specimen's Jones images from the twin's renderer (``twin.scene_renderer``), the
intensities from the physics polariscope (``Optics.polariscope``). The best
hypothesis must leave a residual :data:`MARGIN` times smaller than the next.
"""
from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass, replace
from typing import TYPE_CHECKING, Sequence

import numpy as np

from ..dataset.camera import demosaic, filter_colours, raw_frame
from ..physics.polariscope import ANALYZERS, INPUT_QWP_SETTINGS, OUTPUT_QWP_SETTINGS
from .config import (DEFAULT_SPECIMEN_DEFINES, GenICamCamera, KnownSpecimen, RigConfig, TwinCamera, camera_bands,
                     load_calibration)
from .errors import RigError
from .twin import Optics, analyser_images, pixel_means, scene_renderer

if TYPE_CHECKING:
    from .calibration import Calibration, Exposure

AS_BUILT = "as built"
MIRRORED = "mirrored"
SIGN_FLIPPED = "sign-flipped"
MIRRORED_AND_SIGN_FLIPPED = "mirrored and sign-flipped"
# QWP1 (turned by hand) outermost, starting at 90 where the free-space sweep leaves it.
SETTINGS = tuple((qwp1, qwp2) for qwp1 in reversed(INPUT_QWP_SETTINGS) for qwp2 in OUTPUT_QWP_SETTINGS)
# The next best hypothesis must leave at least this times the residual of the best.
MARGIN = 3.0
# A specimen whose predictions under two hypotheses differ by less (rms, in units of the light level)
# cannot tell those rigs apart, whatever the capture.
MIN_SEPARATION = 0.02
# Pixels whose mean sin^2(retardance / 2) exceeds this see the specimen's birefringence (about 1 degree).
INSIDE = 1e-4


class HandednessError(RigError):
    """The rig's handedness is unknown or wrong: the capture would reconstruct a mirrored or sign-flipped stress."""


def hypotheses(optics: Optics) -> dict[str, Optics]:
    """The calibrated ``optics`` and the three rigs that free space cannot tell from it."""
    conjugated = replace(optics, qwp1_swapped=not optics.qwp1_swapped, qwp2_swapped=not optics.qwp2_swapped)
    return {AS_BUILT: optics, MIRRORED: replace(optics, mirrored=not optics.mirrored), SIGN_FLIPPED: conjugated,
            MIRRORED_AND_SIGN_FLIPPED: replace(conjugated, mirrored=not optics.mirrored)}


class SpecimenModel:
    """What the calibrated model predicts the camera sees of ``specimen`` with the stages at ``pose``."""

    def __init__(self, specimen: KnownSpecimen, camera: TwinCamera | GenICamCamera,
                 pose: tuple[float, float]) -> None:
        self.specimen = specimen
        self.pose = tuple(float(angle) for angle in pose)
        self.resolution = tuple(camera.resolution)
        # A real polarisation camera always samples through its micro-polariser mosaic; the twin when told to.
        self.mosaic = camera.model.mosaic if camera.kind == "twin" else True
        self.bands = camera_bands(camera)
        self.colours = filter_colours(self.bands) if self.bands is not None and self.mosaic else None
        jones_of = scene_renderer(specimen.scene, specimen.defines, self.resolution,
                                  getattr(camera, "supersample", 1), getattr(camera, "spp", 1), self.bands)
        self.jones, self.factor = jones_of(*self.pose)
        _, b, c, d = self.jones[0]
        self.inside = pixel_means(b * b + c * c + d * d, self.factor, self.resolution) > INSIDE
        if not self.inside.any():
            raise HandednessError(f"the handedness specimen {specimen.describe()} shows no birefringence in the "
                                  "camera's view: give it a load, or a scene whose specimen is in view")

    def predict(self, optics: Optics, light_level: float, settings: Sequence[tuple[float, float]]) -> np.ndarray:
        """``(len(settings) * 4, pixels inside)`` intensities at ``settings`` ((QWP1, QWP2) mount readings),
        demosaicked as the camera's are."""
        predicted = []
        for qwp1, qwp2 in settings:
            images = analyser_images(optics, qwp1, qwp2, self.jones, self.factor, self.resolution, self.bands)
            if self.mosaic:
                images = demosaic(raw_frame(images, self.colours), self.colours)
            predicted.extend(light_level * images[analyzer][..., self.inside] for analyzer in ANALYZERS)
        return np.stack(predicted)

    def require_separation(self, optics: Optics, light_level: float) -> None:
        """Refuse a specimen that looks the same under two hypotheses (too weakly loaded, say)."""
        predicted = {name: self.predict(h, light_level, SETTINGS) for name, h in hypotheses(optics).items()}
        names = list(predicted)
        pairs = [(_rms(predicted[a] - predicted[b]), a, b) for i, a in enumerate(names) for b in names[i + 1:]]
        separation, first, second = min(pairs)
        if separation < MIN_SEPARATION:
            raise HandednessError(
                f"the handedness specimen {self.specimen.describe()} looks the same to a rig {first} and one "
                f"{second} (predictions {separation:.4f} apart, need {MIN_SEPARATION}): load it more, or use a "
                "specimen that is neither mirror-symmetric nor unchanged by a stress sign flip, e.g. the disk with "
                f"an oblique load_direction = {DEFAULT_SPECIMEN_DEFINES['load_direction']!r}")

    def judge(self, calibration: Calibration, exposures: Sequence[Exposure]) -> HandednessCheck:
        """The :class:`HandednessCheck` of ``exposures`` (``calibration.Exposure`` at :data:`SETTINGS`)."""
        measured = np.stack([exposure.images[analyzer][..., self.inside]
                             for exposure in exposures for analyzer in ANALYZERS])
        settings = [(exposure.qwp1, exposure.qwp2) for exposure in exposures]
        residuals = {name: _rms(self.predict(optics, calibration.light_level, settings) - measured)
                     for name, optics in hypotheses(calibration.optics).items()}
        return HandednessCheck(self.specimen, self.pose, int(self.inside.sum()), residuals, calibration.optics)


def _rms(values):
    return float(np.sqrt(np.mean(np.square(values))))


@dataclass
class HandednessCheck:
    specimen: KnownSpecimen
    pose: tuple                  # (azimuth, elevation) read back from the stages, degrees
    pixels: int                  # inside the specimen, compared
    residuals: dict              # rms per hypothesis, in units of the light level
    optics: object               # the calibrated optics the hypotheses started from

    @property
    def found(self) -> str:
        return min(self.residuals, key=self.residuals.get)

    @property
    def margin(self) -> float:
        """The next best hypothesis's residual over the best one's."""
        best, runner_up = sorted(self.residuals.values())[:2]
        return runner_up / max(best, np.finfo(float).tiny)

    def findings(self) -> list[tuple[str, str]]:
        """``[(what the capture matches, what to check)]``; empty when the rig is as built."""
        findings = []
        if self.found in (MIRRORED, MIRRORED_AND_SIGN_FLIPPED):
            findings.append(("a mirrored rig", "every angle turns the other way: does the ELL14 turn the other way, "
                                               "is the QWP1 scale read the other way, or is the camera image flipped?"))
        flipped = self.found in (SIGN_FLIPPED, MIRRORED_AND_SIGN_FLIPPED)
        swapped = [name.upper() for name in ("qwp1", "qwp2") if getattr(self.optics, f"{name}_swapped") != flipped]
        if len(swapped) == 2:
            findings.append(("a reversed stress sign", "are both waveplates' fast-axis marks on their slow axes, or "
                                                       "is the specimen's stress-optic coefficient of the other sign "
                                                       "than its scene says?"))
        elif swapped:
            findings.append((f"a swapped {swapped[0]}", f"{swapped[0]}'s fast axis is 90 degrees from its mark: check "
                                                        "the waveplate's fast-axis mark"))
        return findings

    @property
    def verified(self) -> bool:
        return self.margin >= MARGIN and not self.findings()

    def diagnosis(self) -> str:
        """One line: why the handedness is not verified and what to check."""
        residuals = f"residuals {self._residuals()}"
        if self.margin < MARGIN:
            return (f"handedness check on {self.specimen.describe()}: no clear answer ({residuals}; the best, "
                    f"{self.found}, leads by {self.margin:.2f}x, need {MARGIN:g}x): is the specimen in view, "
                    "loaded and turned as the rig file says, and is the camera image read out unflipped?")
        findings = self.findings()
        return (f"handedness check on {self.specimen.describe()}: the capture matches "
                f"{' and '.join(what for what, _ in findings)} ({residuals}): "
                f"{'; '.join(check for _, check in findings)}")

    def _residuals(self):
        return ", ".join(f"{name} {value:.4f}" for name, value in self.residuals.items())

    def describe(self) -> str:
        verdict = "verified" if self.verified else "NOT verified"
        return (f"handedness {verdict} on {self.specimen.describe()} over {self.pixels} pixels: residuals "
                f"{self._residuals()}; best {self.found} by {self.margin:.1f}x (need {MARGIN:g}x)")

    def to_dict(self) -> dict:
        return {"verified": self.verified, "specimen": asdict(self.specimen),
                "pose": {"azimuth": self.pose[0], "elevation": self.pose[1]}, "pixels": self.pixels,
                "residuals": dict(self.residuals), "found": self.found, "margin": self.margin}


def require_unswapped(optics: Optics) -> None:
    """Without the check, refuse optics with a swapped waveplate: free space cannot tell which plate it is."""
    if optics.qwp1_swapped or optics.qwp2_swapped:
        raise HandednessError("the free-space sweep shows a waveplate with its fast and slow axes swapped, and only "
                              "the handedness check can tell which one: check both plates' fast-axis marks, or "
                              "calibrate with the specimen of known stress (without --skip-handedness)")


def capture_record(config: RigConfig) -> dict:
    """The handedness record of the calibration ``config`` applies: the check's, or ``verified: false`` and why."""
    if config.calibration is None:
        return {"verified": False, "reason": "the rig file names no calibration"}
    record = load_calibration(config.calibration)[1].get("handedness")
    if record is None:
        return {"verified": False, "reason": f"{config.calibration} predates the handedness check"}
    if record.get("verified") is not True:
        return {"verified": False, "reason": record.get("reason", f"{config.calibration} records a failed check")}
    return record


def admit(config: RigConfig, unverified_handedness: bool = False) -> dict:
    """The handedness record a capture with ``config`` goes out with; an unverified one only when told to."""
    record = capture_record(config)
    if record["verified"]:
        return record
    if not unverified_handedness:
        raise HandednessError(f"the rig's handedness is unverified ({record['reason']}): a capture could be mirrored "
                              "or sign-flipped; run mi-nest calibrate with the known specimen, or pass "
                              "--unverified-handedness to capture anyway")
    warnings.warn(f"capturing with an unverified handedness ({record['reason']}): the dataset records it; its stress "
                  "may be mirrored or of the wrong sign", UserWarning, stacklevel=3)
    return record
