"""The rig description (``RIG.toml``) that ``mi-nest acquire`` and ``mi-nest calibrate`` run from.

One file names everything that differs between the digital twin and the real
rig: the devices' URLs (``aptsim://``/``ell14sim://`` or ``/dev/ttyUSB0``), the
camera back-end, the schedule of specimen rotations, the timing, and the
calibration to apply. A typo must not cost a three-hour capture, so unknown and
missing keys are errors that name the section and the key.
"""
from __future__ import annotations

import functools
import json
import math
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from urllib.parse import urlsplit

from ..dataset.camera import CameraModel
from ..dataset.schedule import RotationSchedule
from ..io.toml import read_toml
from .twin import Optics

SIMULATED_SCHEMES = {"azimuth": "aptsim", "elevation": "aptsim", "qwp2": "ell14sim"}
QWP1_MODES = ("manual",)


class RigConfigError(ValueError):
    """The rig file is missing, unreadable, or has a missing, unknown or invalid key."""


@dataclass(frozen=True)
class Devices:
    azimuth: str                 # HDR50 stage turning the specimen about the image's vertical
    elevation: str               # HDR50 stage tipping it towards the camera
    qwp2: str                    # ELL14 turning the camera-side quarter-wave plate
    azimuth_channel: int = 1
    elevation_channel: int = 1
    qwp2_address: str = "0"

    @property
    def simulated(self) -> bool:
        return all(urlsplit(getattr(self, name)).scheme == scheme for name, scheme in SIMULATED_SCHEMES.items())


@dataclass(frozen=True)
class TwinCamera:
    """The digital twin's camera: a shipped scene rendered through imperfect ``optics`` and ``model``."""
    scene: str
    defines: dict = field(default_factory=dict)
    resolution: tuple = (32, 32)
    supersample: int = 2
    spp: int = 1
    exposure: float = 0.05               # seconds, spent on the rig's clock
    model: CameraModel = CameraModel()
    optics: Optics = Optics()            # the truth calibration has to find
    bands: str | None = None             # a colour camera's (camera_bands); None: monochrome

    kind = "twin"


@dataclass(frozen=True)
class GenICamCamera:
    """A real polarisation camera through GenICam (``mi_nest.rig.genicam``, an optional extra).

    ``scene`` (with ``defines``) describes the specimen, its material and the
    camera's geometry, as measured on the rig: reconstruction needs them.
    """
    cti: str                             # the camera maker's GenTL producer
    scene: str
    defines: dict = field(default_factory=dict)
    resolution: tuple = (2448, 2048)     # the raw frame, demosaicked to the same size
    serial: str | None = None            # which camera, when several are connected
    exposure: float = 0.05               # seconds
    white_level: float = 4095.0          # raw counts of free space between parallel polarisers
    bands: str | None = None             # a colour polarisation camera's (camera_bands); None: monochrome
    pixel_format: str | None = None      # the raw frame's GenICam PixelFormat (None: RAW_FORMATS)

    kind = "genicam"

    @property
    def raw_format(self) -> str:
        return self.pixel_format or RAW_FORMATS[self.bands is not None]


# The raw (undemosaicked) pixel format of a monochrome and of a colour polarisation camera (LUCID's names).
RAW_FORMATS = {False: "Mono12", True: "BayerRG12"}


@functools.cache
def _parsed_bands(text: str):
    from ..physics.bands import parse_bands
    return parse_bands(text)


def camera_bands(camera: TwinCamera | GenICamCamera):
    """The :class:`~mi_nest.physics.bands.BandSet` a colour camera records (``[camera] bands``: ``rgb``, wavelengths
    in nm such as ``450,532,650``, or a CSV of the sensor's curves); None for a monochrome camera."""
    return None if camera.bands is None else _parsed_bands(camera.bands)


# ``[schedule]`` without keys: the paper's 400 rotations.
RIG_SCHEDULE = RotationSchedule(azimuths=25, elevations=16, elevation_range=90.0)


@dataclass(frozen=True)
class Timing:
    """Seconds and speeds: ``settle`` is waited before every exposure; the rest feeds the dry run's estimate."""
    settle: float = 0.5
    stage_speed: float = 10.0            # degrees per second (HDR50 default velocity profile)
    qwp2_seconds_per_turn: float = 1.5   # ELL14 full turn
    readback: float = 0.2                # position reads and protocol round trips per frame
    qwp1_change: float = 60.0            # the operator turning the manual QWP1


# The disk in diametral compression with its load axis 30 degrees counter-clockwise from image up: neither
# mirror-symmetric nor unchanged by a stress sign flip, and about one fringe at its centre.
DEFAULT_SPECIMEN_DEFINES = {"load": 150.0, "contact_width": 4.0, "load_direction": "-0.5, 0.8660254, 0"}


@dataclass(frozen=True)
class KnownSpecimen:
    """The specimen of known stress ``mi-nest calibrate`` checks the rig's handedness on (``[handedness]``):
    a scene (shipped name or file) and its ``$NAME`` values. The real specimen must be what the scene says:
    its stress sign, load and orientation in the image are what the check compares against."""
    scene: str = "disk_compression"
    defines: dict = field(default_factory=lambda: dict(DEFAULT_SPECIMEN_DEFINES))

    def describe(self) -> str:
        return f"{self.scene} ({', '.join(f'{k}={v}' for k, v in self.defines.items())})"


@dataclass(frozen=True)
class RigConfig:
    devices: Devices
    camera: TwinCamera | GenICamCamera
    schedule: RotationSchedule = RIG_SCHEDULE
    timing: Timing = Timing()
    qwp1_mode: str = "manual"
    retries: int = 3                     # further attempts of a failed frame before the run stops
    retry_wait: float = 2.0              # seconds before reconnecting and trying again
    dolp_threshold: float = 0.95
    calibration: Path | None = None
    source: Path | None = None           # the TOML file, for messages
    handedness: KnownSpecimen = KnownSpecimen()

    def calibrated_optics(self) -> Optics | None:
        """The optics fitted by ``mi-nest calibrate`` (None when no calibration file is given)."""
        if self.calibration is None:
            return None
        return load_calibration(self.calibration)[0]

    def to_dict(self) -> dict:
        """Plain values for the journal and ``dataset.json`` (the rig a dataset was captured with)."""
        camera = asdict(self.camera)
        camera["kind"] = self.camera.kind
        camera["resolution"] = list(self.camera.resolution)
        return {"devices": asdict(self.devices), "camera": camera, "schedule": asdict(self.schedule),
                "timing": asdict(self.timing), "qwp1": {"mode": self.qwp1_mode}, "retries": self.retries,
                "retry_wait": self.retry_wait, "dolp_threshold": self.dolp_threshold,
                "calibration": None if self.calibration is None else str(self.calibration),
                "handedness": asdict(self.handedness)}


def load_calibration(path: str | Path) -> tuple[Optics, dict]:
    """``(Optics, the calibration's dict)`` from a file written by ``mi-nest calibrate``."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        return Optics(**data["optics"]), data
    except FileNotFoundError as error:
        raise RigConfigError(f"calibration file not found: {path}") from error
    except (json.JSONDecodeError, KeyError, TypeError) as error:
        raise RigConfigError(f"{path}: not a calibration written by mi-nest calibrate ({error})") from error


def _take(table, where, required=(), optional=()):
    """The keys of ``table`` after checking that every required key is there and no unknown one is."""
    if not isinstance(table, dict):
        raise RigConfigError(f"[{where}] must be a table, got {table!r}")
    missing = [k for k in required if k not in table]
    if missing:
        raise RigConfigError(f"[{where}] is missing {', '.join(repr(k) for k in missing)}")
    unknown = sorted(set(table) - set(required) - set(optional))
    if unknown:
        raise RigConfigError(f"[{where}] has unknown key(s) {unknown}; known: {sorted(set(required) | set(optional))}")
    return table


def _number(where, key, value, least=None, above=None):
    """``[where] key`` as a float: a finite number (TOML has nan and inf), at least ``least`` or above ``above``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or \
            (least is not None and value < least) or (above is not None and value <= above):
        bound = f" >= {least:g}" if least is not None else f" > {above:g}" if above is not None else ""
        raise RigConfigError(f"[{where}] {key} must be a finite number{bound}, got {value!r}")
    return float(value)


def _whole(where, key, value, least=0):
    """``[where] key``: an integer (not a float, not a bool) of at least ``least``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise RigConfigError(f"[{where}] {key} must be an integer, got {value!r}")
    if value < least:
        raise RigConfigError(f"[{where}] {key} must be an integer >= {least}, got {value!r}")
    return value


def _dataclass_options(default, table, where):
    """``default`` (a dataclass instance) with the values of ``table`` in place of its own: integers where it
    has integers, finite numbers where it has numbers (or None); true or false is the dataclass's to check."""
    _take(table, where, optional=[f.name for f in fields(default)])
    for key, value in table.items():
        own = getattr(default, key)
        if isinstance(own, bool):
            continue
        if isinstance(own, int):
            _whole(where, key, value)
        elif isinstance(own, float) or (own is None and isinstance(value, (int, float))):
            _number(where, key, value)
    try:
        return replace(default, **table)
    except (TypeError, ValueError) as error:
        raise RigConfigError(f"[{where}]: {error}") from error


def _camera(table, source):
    kind = table.get("kind")
    if kind == "genicam":
        return _checked_bands(_genicam_camera(table), source, mosaic=True)
    if kind != "twin":
        raise RigConfigError(f"[camera] kind = {kind!r}: 'twin' (the digital twin) or 'genicam' (a real "
                             "polarisation camera through harvesters, an optional extra)")
    _take(table, "camera", required=("kind", "scene"),
          optional=("defines", "resolution", "supersample", "spp", "exposure", "model", "optics", "bands"))
    resolution = tuple(table.get("resolution", (32, 32)))
    if len(resolution) != 2 or not all(isinstance(n, int) and n > 0 for n in resolution):
        raise RigConfigError(f"[camera] resolution must be [width, height] in pixels, got {table.get('resolution')}")
    for name in ("supersample", "spp"):
        if not (isinstance(table.get(name, 1), int) and table.get(name, 1) >= 1):
            raise RigConfigError(f"[camera] {name} must be a positive integer, got {table[name]!r}")
    if not isinstance(table.get("defines", {}), dict):
        raise RigConfigError(f"[camera.defines] must be a table of the scene's $NAME values, got {table['defines']!r}")
    camera = TwinCamera(scene=str(table["scene"]), defines=dict(table.get("defines", {})),
                        resolution=resolution, supersample=table.get("supersample", 2), spp=table.get("spp", 1),
                        exposure=_number("camera", "exposure", table.get("exposure", 0.05), above=0),
                        model=_dataclass_options(CameraModel(), table.get("model", {}), "camera.model"),
                        optics=_dataclass_options(Optics(), table.get("optics", {}), "camera.optics"),
                        bands=table.get("bands"))
    return _checked_bands(camera, source, mosaic=camera.model.mosaic)


def _checked_bands(camera, source, mosaic):
    """``camera`` with its ``bands`` checked (a CSV's path made relative to the rig file): bands that no camera has,
    or a colour mosaic with other than three, are refused before anything moves."""
    from ..dataset.camera import bayer_sites
    from ..physics.bands import BandError
    text = camera.bands
    if text is None:
        return camera
    if not isinstance(text, str):
        raise RigConfigError(f"[camera] bands must be a string: 'rgb', wavelengths in nm such as '450,532,650', or a "
                             f"CSV file of the sensor's curves; got {text!r}")
    if text.strip().lower().endswith(".csv") and source is not None and not Path(text).is_absolute():
        camera = replace(camera, bands=str(Path(source).parent / text))
    try:
        bands = camera_bands(camera)
        if mosaic:
            bayer_sites(bands)
    except (BandError, ValueError) as error:
        raise RigConfigError(f"[camera] bands = {text!r}: {error}") from None
    return camera


def _genicam_camera(table):
    _take(table, "camera", required=("kind", "cti", "scene"),
          optional=("defines", "resolution", "serial", "exposure", "white_level", "bands", "pixel_format"))
    options = {k: v for k, v in table.items() if k != "kind"}
    if "resolution" in options:
        options["resolution"] = tuple(options["resolution"])
    for key in ("exposure", "white_level"):
        if key in options:
            options[key] = _number("camera", key, options[key], above=0)
    return GenICamCamera(**options)


def parse(data: dict, source: str | Path | None = None) -> RigConfig:
    """A :class:`RigConfig` from the TOML document ``data`` (``source``: its path, for relative paths)."""
    _take(data, "top level", required=("devices", "camera"),
          optional=("schedule", "timing", "qwp1", "acquisition", "calibration", "handedness"))
    devices = _take(data["devices"], "devices", required=("azimuth", "elevation", "qwp2"),
                    optional=("azimuth_channel", "elevation_channel", "qwp2_address"))
    for key in ("azimuth_channel", "elevation_channel"):
        _whole("devices", key, devices.get(key, 1), least=1)
    devices = Devices(**devices)
    camera = _camera(data["camera"], source)
    if camera.kind == "twin" and not devices.simulated:
        raise RigConfigError(f"[camera] kind = 'twin' renders what simulated devices report; the devices must be "
                             f"{', '.join(f'{n} = {s}://NAME' for n, s in SIMULATED_SCHEMES.items())}, got "
                             f"{asdict(devices)}")
    schedule = _dataclass_options(RIG_SCHEDULE, data.get("schedule", {}), "schedule")
    try:
        schedule.rotations()
    except ValueError as error:
        raise RigConfigError(f"[schedule]: {error}") from error
    timing = _dataclass_options(Timing(), data.get("timing", {}), "timing")
    for key, value in asdict(timing).items():
        speed = key in ("stage_speed", "qwp2_seconds_per_turn")
        _number("timing", key, value, least=None if speed else 0, above=0 if speed else None)
    qwp1 = _take(data.get("qwp1", {}), "qwp1", optional=("mode",))
    mode = qwp1.get("mode", "manual")
    if mode not in QWP1_MODES:
        raise RigConfigError(f"[qwp1] mode = {mode!r}: QWP1 sits in a manual mount; only {QWP1_MODES} is supported")
    acquisition = _take(data.get("acquisition", {}), "acquisition",
                        optional=("retries", "retry_wait", "dolp_threshold"))
    retries = acquisition.get("retries", 3)
    if not (isinstance(retries, int) and retries >= 0):
        raise RigConfigError(f"[acquisition] retries must be an integer >= 0, got {retries!r}")
    calibration = data.get("calibration")
    if calibration is not None:
        calibration = Path(calibration)
        if source is not None and not calibration.is_absolute():
            calibration = Path(source).parent / calibration
    retry_wait = _number("acquisition", "retry_wait", acquisition.get("retry_wait", 2.0), least=0)
    dolp_threshold = _number("acquisition", "dolp_threshold", acquisition.get("dolp_threshold", 0.95), above=0)
    if dolp_threshold > 1:
        raise RigConfigError(f"[acquisition] dolp_threshold is a degree of linear polarisation, at most 1, got "
                             f"{dolp_threshold:g}")
    return RigConfig(devices, camera, schedule, timing, mode, retries, retry_wait, dolp_threshold, calibration,
                     None if source is None else Path(source), _known_specimen(data.get("handedness", {})))


def _known_specimen(table):
    """``[handedness]``: without ``scene``, the default disk with ``defines`` overriding its values."""
    _take(table, "handedness", optional=("scene", "defines"))
    defines = table.get("defines", {})
    if not isinstance(defines, dict):
        raise RigConfigError(f"[handedness.defines] must be a table of the scene's $NAME values, got {defines!r}")
    if "scene" not in table:
        return KnownSpecimen(defines={**DEFAULT_SPECIMEN_DEFINES, **defines})
    return KnownSpecimen(str(table["scene"]), dict(defines))


def load(path: str | Path) -> RigConfig:
    """Read and check ``RIG.toml``; a shipped name (``rig_twin``) finds the file among the shipped scenes."""
    path = Path(path)
    if not path.is_file() and path.suffix == "" and not path.parent.name:
        from ..scene import scene_path
        path = scene_path("disk_compression").parent / f"{path.name}.toml"
    try:
        data = read_toml(path, "rig file")
    except ValueError as error:
        raise RigConfigError(str(error)) from error
    try:
        return parse(data, path)
    except RigConfigError as error:
        raise RigConfigError(f"{path}: {error}") from error
