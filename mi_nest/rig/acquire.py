"""Journaled acquisition of a multi-axis polariscope dataset on the rig (``mi-nest acquire``), and its calibration.

A real capture takes hours (the paper: about 3 h for 400 rotations), and USB
links drop, controllers report busy, people trip over cables. So every
exposure is a *frame* that is committed on its own: its four analyser images
and the positions read back from the drivers go to ``frames/<key>.npz``
(written atomically and synced), then one JSON line is appended to
``journal.jsonl`` and synced. The journal line is the commit record: a rerun
of the same command skips every journaled frame and redoes a frame whose file
exists without a line, so nothing captured is lost or taken twice. A frame
whose devices fail is retried a bounded number of times (drivers reopened
after a communication error), then the run stops with the journal intact.

The order of the schedule follows the hardware: QWP1 sits in a manual mount,
so it is the outermost loop (two visits of the operator per dataset); inside,
every specimen rotation (azimuth x elevation, elevation fastest), and per
rotation QWP2 at 0 and 45 degrees on the ELL14, one exposure each (the
polarisation camera takes the four analysers at once). When a rotation's four
frames exist, its EXR is assembled in the dataset format, posed from the
*measured* stage angles, so a captured dataset loads and reconstructs like a
simulated one.

The same code drives the digital twin (simulated devices and camera) and the
real rig; only the URLs in the rig file change.
"""
from __future__ import annotations

import json
import logging
import os
import sys
import warnings
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from ..dataset import format as fmt
from ..dataset.camera import CameraModel
from ..dataset.masks import banded_dolp_mask
from ..dataset.schedule import Rotation, camera_to_world
from ..io.atomic import atomic_path
from ..io.exr import write_channels
from ..io.lock import locked_directory, other_entries
from ..physics.polariscope import ANALYZERS, INPUT_QWP_SETTINGS, OUTPUT_QWP_SETTINGS, measurement_name
from . import handedness
from .calibration import Calibration, Exposure, expected_exposures, fit
from .clock import Clock
from .config import KnownSpecimen, RigConfig, camera_bands
from .errors import CommunicationError, RigError

if TYPE_CHECKING:
    from .genicam import GenICamBackend

log = logging.getLogger(__name__)

JOURNAL = "journal.jsonl"
JOURNAL_FORMAT = "mi_nest.acquisition"
JOURNAL_VERSION = 1
FRAMES = "frames"


class AcquisitionError(RigError):
    """The run cannot go on (a frame failed every attempt, or the directory holds another acquisition)."""


class NoOperatorError(ValueError):
    """Nobody can answer the operator's prompt (its input has ended). Not a device error: never retried."""


@dataclass(frozen=True)
class Frame:
    """One exposure of the schedule: specimen ``rotation``, QWP1 and QWP2 at their nominal angles."""
    number: int
    rotation: Rotation
    qwp1: float
    qwp2: float

    @property
    def key(self) -> str:
        return f"{self.rotation.index:04d}.{self.qwp1:g}.{self.qwp2:g}"


def schedule(config: RigConfig) -> list[Frame]:
    """Every frame in capture order: QWP1 (by hand) outermost, then rotations, then QWP2."""
    rotations = config.schedule.rotations()
    frames = [(rotation, qwp1, qwp2) for qwp1 in INPUT_QWP_SETTINGS for rotation in rotations
              for qwp2 in OUTPUT_QWP_SETTINGS]
    return [Frame(number, *frame) for number, frame in enumerate(frames)]


def estimate_seconds(config: RigConfig, frames: Sequence[Frame]) -> float:
    """Wall time of ``frames`` on the real rig: stage and waveplate moves at their speeds (one device at a
    time, as the acquisition moves them), settling, exposure, read-backs and the operator's QWP1 turns."""
    timing = config.timing
    azimuth = elevation = qwp2 = 0.0
    qwp1 = None
    total = 0.0
    for frame in frames:
        if frame.qwp1 != qwp1:
            total += timing.qwp1_change
            qwp1 = frame.qwp1
        total += (abs(frame.rotation.azimuth - azimuth) + abs(frame.rotation.elevation - elevation)) / timing.stage_speed
        azimuth, elevation = frame.rotation.azimuth, frame.rotation.elevation
        total += abs(frame.qwp2 - qwp2) / 360.0 * timing.qwp2_seconds_per_turn
        qwp2 = frame.qwp2
        total += timing.settle + config.camera.exposure + timing.readback
    return total


def _duration(seconds):
    hours, rest = divmod(round(seconds), 3600)
    return f"{hours} h {rest // 60:02d} min {rest % 60:02d} s"


def dry_run(config: RigConfig, out: Callable[[str], None] = print, shown: int = 6) -> float:
    """Print the schedule (counts, the first frames) and its estimated duration; return the estimate (s)."""
    frames = schedule(config)
    rotations = config.schedule.rotations()
    optics = config.calibrated_optics()
    seconds = estimate_seconds(config, frames)
    out(f"{len(rotations)} rotations ({config.schedule.azimuths} azimuths over {config.schedule.azimuth_range:g} deg "
        f"x {config.schedule.elevations} elevations over {config.schedule.elevation_range:g} deg; "
        f"{sum(r.split == 'test' for r in rotations)} held out for testing)")
    out(f"{len(frames)} frames = {len(INPUT_QWP_SETTINGS)} QWP1 settings (turned by hand) x {len(rotations)} "
        f"rotations x {len(OUTPUT_QWP_SETTINGS)} QWP2 settings; {len(frames) * len(ANALYZERS)} analyser images, "
        f"{len(fmt.CHANNELS)} channels per rotation")
    out("calibration: " + ("none (nominal angles)" if optics is None else
                           f"{config.calibration} (QWP1 offset {optics.qwp1_offset:.3f} deg, "
                           f"QWP2 offset {optics.qwp2_offset:.3f} deg)"))
    record = handedness.capture_record(config)
    out("handedness: " + ("verified" if record["verified"] else
                          f"unverified ({record['reason']}): acquire refuses it without --unverified-handedness"))
    for frame in frames[:shown]:
        out(f"  frame {frame.number}: {frame.key}  azimuth {frame.rotation.azimuth:g}  elevation "
            f"{frame.rotation.elevation:g}  QWP1 {frame.qwp1:g}  QWP2 {frame.qwp2:g}")
    if len(frames) > shown:
        out(f"  ... {len(frames) - shown} more")
    out(f"estimated duration {_duration(seconds)} ({seconds / len(rotations):.1f} s per rotation; stages at "
        f"{config.timing.stage_speed:g} deg/s, QWP2 {config.timing.qwp2_seconds_per_turn:g} s per turn, settle "
        f"{config.timing.settle:g} s, exposure {config.camera.exposure:g} s, {config.timing.qwp1_change:g} s per "
        "QWP1 change)")
    return seconds


# --- the rig ---------------------------------------------------------------------------------------
class TwinBackend:
    """The twin's camera: renders what the simulated devices' true positions show (never what was commanded)."""

    def __init__(self, config: RigConfig, free_space: bool = False) -> None:
        from . import sim, twin
        from .sim import protocol_aptsim
        camera = config.camera
        devices = config.devices
        self.config = config

        def true_state() -> tuple[float, float, float]:
            qwp2 = sim.device(devices.qwp2)
            return (sim.device(devices.azimuth).position() / protocol_aptsim.COUNTS_PER_DEGREE,
                    sim.device(devices.elevation).position() / protocol_aptsim.COUNTS_PER_DEGREE,
                    qwp2.current_position() * 360.0 / qwp2.pulses)

        self.bands = camera_bands(camera)
        if free_space:
            jones_of = twin.free_space
        else:
            jones_of = twin.scene_renderer(camera.scene, camera.defines, camera.resolution, camera.supersample,
                                           camera.spp, self.bands)
        self.camera = twin.SimulatedCamera(jones_of, true_state, camera.optics, camera.model, camera.resolution,
                                           self.bands)

    def set_qwp1(self, reading: float) -> None:
        """The operator's turn of the manual plate, in the twin's world."""
        self.camera.qwp1 = reading

    def put_in_view(self, specimen: KnownSpecimen) -> None:
        """The operator's placing of ``specimen`` (a ``config.KnownSpecimen``), in the twin's world."""
        from . import twin
        camera = self.config.camera
        self.camera.show(twin.scene_renderer(specimen.scene, specimen.defines, camera.resolution, camera.supersample,
                                             camera.spp, self.bands))

    def capture(self, frame_number: int, clock: Clock) -> dict[int, np.ndarray]:
        # the noise of a frame is seeded by its number, so a resumed run captures what an uninterrupted one would
        self.camera.exposures = frame_number
        images = self.camera.capture()
        clock.sleep(self.config.camera.exposure)
        return images

    def close(self) -> None:
        """Nothing to release: the twin renders in this process."""


def scene_index(config: RigConfig) -> dict:
    """``dataset.json`` fields from the rig's scene: camera reference, specimen centre, material."""
    from ..dataset.simulate import SimulationSettings, dataset_index
    from ..scene import load_scene
    camera = config.camera
    width, height = camera.resolution
    defines = {**camera.defines, "res": width}
    spp = getattr(camera, "spp", 1)
    scene = load_scene(camera.scene, **defines, spp=spp)
    settings = SimulationSettings(**asdict(config.schedule), spp=spp, camera=getattr(camera, "model", CameraModel()),
                                  dolp_threshold=config.dolp_threshold, bands=camera_bands(camera))
    index = dataset_index(scene, camera.scene, defines, settings)
    if index["resolution"] != [width, height]:
        raise AcquisitionError(f"the rig's scene {camera.scene} renders {index['resolution']}, the rig file asks for "
                               f"{[width, height]}; the scene's film must follow $res")
    if camera.kind != "twin":
        # A real camera's noise is what it is: record the camera, not a simulated model.
        index["camera_model"] = {"kind": camera.kind, "serial": camera.serial, "exposure": camera.exposure,
                                 "white_level": camera.white_level}
    return index


def camera_backend(config: RigConfig, free_space: bool = False) -> TwinBackend | GenICamBackend:
    """The camera of the rig file: the twin (free space: no specimen, for calibration) or a GenICam camera."""
    if config.camera.kind == "genicam":
        from .genicam import GenICamBackend
        return GenICamBackend(config)
    return TwinBackend(config, free_space=free_space)


class Rig:
    """The drivers of the two stages and the QWP2 mount, the camera, and the operator for the manual QWP1."""

    def __init__(self, config: RigConfig, operator: Callable[[str], None], free_space: bool = False) -> None:
        self.config = config
        self.operator = operator
        self.camera = camera_backend(config, free_space=free_space)
        self.azimuth = self.elevation = self.qwp2 = None
        self.reopen()

    def reopen(self) -> None:
        """Open (again, after a lost link) every driver; the devices keep their positions."""
        from .ell14 import ELL14
        from .hdr50 import HDR50
        self.close_drivers()
        devices = self.config.devices
        self.azimuth = HDR50(devices.azimuth, channel=devices.azimuth_channel)
        self.elevation = HDR50(devices.elevation, channel=devices.elevation_channel)
        self.qwp2 = ELL14(devices.qwp2, address=devices.qwp2_address)

    @property
    def clock(self) -> Clock:
        return self.azimuth.clock

    def home(self) -> None:
        self.azimuth.home()
        self.elevation.home()
        self.qwp2.home()

    def set_qwp1(self, nominal: float, reading: float) -> None:
        self.operator(f"Turn QWP1 (manual mount) to {reading:.2f} deg on its scale (nominal {nominal:g} deg), "
                      "then press Enter")
        self.camera.set_qwp1(reading)

    def positions(self) -> tuple[float, float, float]:
        """The measured (azimuth, elevation, qwp2), read back from the drivers."""
        return self.azimuth.position(), self.elevation.position(), self.qwp2.position()

    def close_drivers(self) -> None:
        for driver in (self.azimuth, self.elevation, self.qwp2):
            if driver is not None:
                driver.close()
        self.azimuth = self.elevation = self.qwp2 = None

    def close(self) -> None:
        self.close_drivers()
        self.camera.close()


def terminal_operator(message: str) -> None:
    """Ask the person at the rig and wait for Enter."""
    try:
        input(f"{message}: ")
    except EOFError:
        raise NoOperatorError("the run waits for the operator at the manual QWP1, but its input has ended (no "
                              "terminal); pass --yes to run unattended") from None


def unattended_operator(message: str) -> None:
    """``--yes``: say what would be asked and go on (the twin turns its plate itself)."""
    print(f"[--yes] {message}", file=sys.stderr)


# --- the journal -----------------------------------------------------------------------------------
def _identity(config, optics):
    """What a rerun must agree on to continue a journal: the same images, angles and corrections."""
    rig = config.to_dict()
    return {"camera": rig["camera"], "schedule": rig["schedule"],
            "calibration": None if optics is None else optics.to_dict()}


def _append_line(path, record):
    with open(path, "a") as journal:
        journal.write(json.dumps(record, default=fmt.plain) + "\n")
        journal.flush()
        os.fsync(journal.fileno())


def read_journal(path: str | Path) -> tuple[dict, dict[str, dict]]:
    """``(header, {key: record})``. A last line cut short by a crash is no commit: it is dropped from the file."""
    text = Path(path).read_text()
    lines = text.split("\n")
    records = []
    for number, line in enumerate(lines):
        if not line:
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError as error:
            if number == len(lines) - 1:     # torn final write: the frame was never committed
                log.warning("%s: dropping an incomplete last line", path)
                with atomic_path(path, ".jsonl") as tmp:
                    Path(tmp).write_text("\n".join(lines[:-1]) + "\n")
                break
            raise AcquisitionError(f"{path}: line {number + 1} is corrupt ({error})") from error
    if not records or records[0].get("journal") != JOURNAL_FORMAT:
        raise AcquisitionError(f"{path}: not an mi_nest acquisition journal")
    header, frames = records[0], {}
    for record in records[1:]:
        if record["key"] in frames:
            raise AcquisitionError(f"{path}: frame {record['key']} is journaled twice")
        frames[record["key"]] = record
    return header, frames


def _write_frame(path, images, record):
    """The frame's images (``(H, W)``, or ``(bands, H, W)`` from a colour camera) and read-back positions, on disk
    (``atomic_path`` syncs them) before its journal line commits it."""
    with atomic_path(path, ".npz") as tmp:
        np.savez(tmp, **{f"analyzer_{a}": np.asarray(images[a], dtype=np.float32) for a in ANALYZERS},
                 **{name: np.float64(record[name]) for name in ("azimuth", "elevation", "qwp2_measured")})


def _read_frame(path):
    with np.load(path) as data:
        return {a: data[f"analyzer_{a}"] for a in ANALYZERS}


def _readable_frame(path):
    try:
        _read_frame(path)
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile):
        return False
    return True


def _drop_from_journal(path, keys):
    """Rewrite the journal without the commit lines of the frames ``keys``."""
    lines = [line for line in Path(path).read_text().splitlines() if json.loads(line).get("key") not in keys]
    with atomic_path(path, ".jsonl") as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")


# --- acquisition -----------------------------------------------------------------------------------
@dataclass
class AcquisitionReport:
    directory: Path
    captured: int          # frames taken by this run
    kept: int              # frames journaled by an earlier run
    retries: int           # frame attempts that failed and were repeated
    rig_seconds: float     # on the rig's clock (simulated for the twin)

    def describe(self) -> str:
        return (f"{self.captured} frames captured, {self.kept} kept from an earlier run, {self.retries} "
                f"retried after device errors; {self.rig_seconds:.0f} s on the rig's clock")


class _Acquisition:
    def __init__(self, config, output, operator, on_frame, on_retry, handedness_record):
        self.config = config
        self.handedness = handedness_record
        self.output = Path(output)
        self.operator = operator
        self.on_frame = on_frame
        self.on_retry = on_retry
        self.optics = config.calibrated_optics()
        self.frames = schedule(config)
        self.rotations = config.schedule.rotations()
        self.journal = self.output / JOURNAL
        self.retries = 0
        self._qwp1 = None
        self._stale = False

    def open_journal(self) -> dict[str, dict]:
        identity = _identity(self.config, self.optics)
        if self.journal.exists():
            header, done = read_journal(self.journal)
            if header["identity"] != json.loads(json.dumps(identity)):
                raise AcquisitionError(f"{self.output} holds an acquisition with another camera, schedule or "
                                       "calibration; choose a new directory or delete it")
            self._retake_unreadable(done)
            return done
        if other_entries(self.output):
            raise AcquisitionError(f"{self.output} exists and holds no acquisition journal; choose an empty directory")
        (self.output / FRAMES).mkdir(parents=True, exist_ok=True)
        _append_line(self.journal, {"journal": JOURNAL_FORMAT, "version": JOURNAL_VERSION, "identity": identity,
                                    "rig": self.config.to_dict(), "frames": len(self.frames)})
        return {}

    def _retake_unreadable(self, done):
        """Forget the journaled frames that a rotation still to be assembled needs but whose files cannot be
        read (damaged on disk): the journal no longer commits them, and this run captures them again."""
        lost = [key for rotation in self.rotations
                if self._complete(rotation, done) and not (self.output / fmt.rotation_file(rotation.index)).is_file()
                for key in self._keys(rotation) if not _readable_frame(self.output / done[key]["file"])]
        if lost:
            log.warning("%s: %d journaled frame file(s) cannot be read (%s); capturing them again", self.output,
                        len(lost), ", ".join(lost))
            for key in lost:
                del done[key]
            _drop_from_journal(self.journal, lost)

    def run(self, progress: bool) -> AcquisitionReport:
        done = self.open_journal()
        kept = len(done)
        self.rig = Rig(self.config, self.operator)
        try:
            started = self.rig.clock.now()
            self.index = scene_index(self.config)
            self._describe_source()
            for rotation in self.rotations:
                if self._complete(rotation, done):
                    self._assemble(rotation, done)
            # Once after the rotations an earlier run completed, then as each new one completes.
            fmt.write_index(self.output, self.index)
            todo = [f for f in self.frames if f.key not in done]
            if todo:
                self.rig.home()
            bar = None
            if progress:
                from tqdm import tqdm
                bar = tqdm(total=len(self.frames), initial=kept, desc="acquire", unit="frame")
            try:
                for frame in todo:
                    done[frame.key] = self._frame(frame)
                    if bar is not None:
                        bar.update()
                    if self._complete(frame.rotation, done):
                        self._assemble(frame.rotation, done)
                        fmt.write_index(self.output, self.index)
                    if self.on_frame is not None:
                        self.on_frame(done[frame.key])
            finally:
                if bar is not None:
                    bar.close()
            self.index["complete"] = True
            fmt.write_index(self.output, self.index)
            return AcquisitionReport(self.output, len(todo), kept, self.retries, self.rig.clock.now() - started)
        finally:
            self.rig.close()

    def _describe_source(self):
        camera = self.config.camera
        self.index["source"] = {"kind": "captured", "camera": camera.kind, "scene": self.index["source"]["scene"],
                                "defines": self.index["source"]["defines"], "rig": self.config.to_dict()}
        self.index["mask_channels"] = ["mask.dolp"]
        self.index["calibration"] = None if self.optics is None else self.optics.to_dict()
        self.index["handedness"] = self.handedness
        self.index["journal"] = JOURNAL
        for entry in self.index["rotations"]:
            entry["nominal"] = {"azimuth": entry["azimuth"], "elevation": entry["elevation"]}
            entry["measured"] = None

    def _frame(self, frame):
        """Capture ``frame`` (retrying after device errors), write it, and commit it to the journal."""
        attempts = self.config.retries + 1
        for attempt in range(1, attempts + 1):
            try:
                record, images = self._capture(frame)
                break
            except RigError as error:
                if attempt == attempts:
                    raise AcquisitionError(
                        f"frame {frame.key} failed {attempts} times; last error: {error}. Every frame before it is "
                        f"journaled in {self.journal}: fix the rig and run the same command again to resume") from error
                self.retries += 1
                log.warning("frame %s, attempt %d of %d: %s", frame.key, attempt, attempts, error)
                if self.on_retry is not None:
                    self.on_retry(frame, error, attempt)
                self._stale = self._stale or isinstance(error, CommunicationError)
                self.rig.clock.sleep(self.config.retry_wait)
        record["attempts"] = attempt
        _write_frame(self.output / record["file"], images, record)
        _append_line(self.journal, record)
        return record

    def _capture(self, frame):
        rig = self.rig
        if self._stale:
            rig.reopen()
            self._stale = False
        if frame.qwp1 != self._qwp1:
            rig.set_qwp1(frame.qwp1, frame.qwp1 - (self.optics.qwp1_offset if self.optics else 0.0))
            self._qwp1 = frame.qwp1
        commanded = frame.qwp2 - (self.optics.qwp2_offset if self.optics else 0.0)
        rig.azimuth.move_to(frame.rotation.azimuth)
        rig.elevation.move_to(frame.rotation.elevation)
        rig.qwp2.move_to(commanded)
        rig.clock.sleep(self.config.timing.settle)
        azimuth, elevation, qwp2 = rig.positions()
        started = rig.clock.now()
        images = rig.camera.capture(frame.number, rig.clock)
        record = {"key": frame.key, "frame": frame.number, "rotation": frame.rotation.index,
                  "split": frame.rotation.split, "qwp1": frame.qwp1, "qwp2": frame.qwp2,
                  "azimuth_nominal": frame.rotation.azimuth, "elevation_nominal": frame.rotation.elevation,
                  "qwp2_commanded": commanded % 360.0, "azimuth": azimuth, "elevation": elevation,
                  "qwp2_measured": qwp2, "exposure_start": started, "exposure_end": rig.clock.now(),
                  "file": f"{FRAMES}/{frame.key}.npz"}
        return record, images

    @staticmethod
    def _keys(rotation):
        return [Frame(0, rotation, b1, b2).key for b1 in INPUT_QWP_SETTINGS for b2 in OUTPUT_QWP_SETTINGS]

    def _complete(self, rotation, done):
        return all(key in done for key in self._keys(rotation))

    def _assemble(self, rotation, done):
        """Pose the rotation from the mean of the stage angles measured at its four frames, and write its EXR
        unless an earlier run wrote it whole (a crash can leave a renamed file cut short: it is written again)."""
        records = [done[k] for k in self._keys(rotation)]
        azimuth = float(np.mean([r["azimuth"] for r in records]))
        elevation = float(np.mean([r["elevation"] for r in records]))
        entry = self.index["rotations"][rotation.index]
        entry.update(azimuth=azimuth, elevation=elevation,
                     to_world=camera_to_world(self.index["camera"]["reference_to_world"],
                                              Rotation(rotation.index, azimuth, elevation, rotation.split),
                                              self.index["specimen_center"]).round(9).tolist(),
                     measured={name: [r[name] for r in records] for name in ("azimuth", "elevation", "qwp2_measured")})
        if not fmt.rotation_is_whole(self.output, entry, self.index):
            bands = camera_bands(self.config.camera)
            channels = {}
            for record in records:
                images = _read_frame(self.output / record["file"])
                for analyser in ANALYZERS:
                    name = measurement_name(record["qwp1"], record["qwp2"], analyser)
                    if bands is None:
                        channels[name] = images[analyser]
                    else:
                        channels.update({f"{band}.{name}": image for band, image in zip(bands.names, images[analyser])})
            channels["mask.dolp"] = banded_dolp_mask(channels, None if bands is None else bands.names,
                                                     self.config.dolp_threshold).astype(np.float32)
            write_channels(self.output / entry["file"], channels, half=True,
                           metadata={**fmt.rotation_header(entry, self.index), "mi_nest.source": "captured"})


def acquire(config: RigConfig, output: str | Path, operator: Callable[[str], None] = unattended_operator,
            progress: bool = True, on_frame: Callable[[dict], None] | None = None,
            on_retry: Callable[[Frame, Exception, int], None] | None = None,
            unverified_handedness: bool = False) -> AcquisitionReport:
    """Capture (or resume capturing) the dataset of ``config`` into ``output``; see the module docstring.

    A calibration without a verified handedness (``handedness.py``) is refused unless ``unverified_handedness``;
    the dataset then records that it is unverified.

    ``operator(message)`` is asked to turn the manual QWP1; ``on_frame(record)`` runs after each frame is
    committed; ``on_retry(frame, error, attempt)`` after each failed attempt, before reconnecting.
    """
    handedness_record = handedness.admit(config, unverified_handedness)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with locked_directory(output):
                return _Acquisition(config, output, operator, on_frame, on_retry, handedness_record).run(progress)
        finally:
            if caught:
                # one summary, not one warning per rendered view of the twin
                warnings.warn(f"{len(caught)} warning(s) during the acquisition; the last: {caught[-1].message}",
                              RuntimeWarning, stacklevel=2)


# --- calibration -----------------------------------------------------------------------------------
def calibrate(config: RigConfig, operator: Callable[[str], None] = unattended_operator,
              check_handedness: bool = True) -> Calibration:
    """The free-space sweep of :func:`~mi_nest.rig.calibration.expected_exposures` on the rig, fitted; then the
    handedness check on the rig file's known specimen (``handedness.py``), which raises
    :class:`~mi_nest.rig.handedness.HandednessError` unless the rig is as built.

    QWP2 positions are the ones read back from the ELL14, not the commanded ones.
    """
    rig = Rig(config, operator, free_space=True)
    try:
        rig.qwp2.home()
        sweep = expected_exposures()
        calibration = fit(_exposures(rig, sweep))
        if check_handedness:
            calibration.handedness = _check_handedness(rig, calibration, len(sweep), qwp1=sweep[-1][0])
            if not calibration.handedness.verified:
                raise handedness.HandednessError(calibration.handedness.diagnosis())
        else:
            handedness.require_unswapped(calibration.optics)
        return calibration
    finally:
        rig.close()


def _exposures(rig, settings, first_number=0, qwp1=None):
    """One exposure per (QWP1, QWP2) mount setting, numbered from ``first_number``; the operator turns QWP1
    (now at ``qwp1``) when it changes, and the QWP2 angle recorded is the one read back."""
    exposures = []
    for number, (qwp1_setting, qwp2_setting) in enumerate(settings, first_number):
        if qwp1_setting != qwp1:
            rig.set_qwp1(qwp1_setting, qwp1_setting)
            qwp1 = qwp1_setting
        rig.qwp2.move_to(qwp2_setting)
        rig.clock.sleep(rig.config.timing.settle)
        measured = rig.qwp2.position()
        exposures.append(Exposure(qwp1_setting, measured, rig.camera.capture(number, rig.clock)))
    return exposures


def _check_handedness(rig, calibration, first_number, qwp1):
    """Home the stages, predict the known specimen there (refusing one that cannot tell the hypotheses apart
    before anyone fetches it), have it put in view, capture and judge it."""
    specimen = rig.config.handedness
    rig.home()
    model = handedness.SpecimenModel(specimen, rig.config.camera, (rig.azimuth.position(), rig.elevation.position()))
    model.require_separation(calibration.optics, calibration.light_level)
    rig.operator(f"Put the specimen of known stress in view at the stages' home: {specimen.describe()}; then "
                 "press Enter")
    rig.camera.put_in_view(specimen)
    return model.judge(calibration, _exposures(rig, handedness.SETTINGS, first_number, qwp1))
