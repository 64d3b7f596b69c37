"""The on-disk dataset: ``dataset.json`` plus one multichannel EXR per rotation.

The same format holds simulations and real captures (``source.kind``). Each
rotation's EXR has the 16 ``pol.<b1>.<b2>.<a2>`` channels (normalised
intensities, half float, ZIP), ``mask.dolp`` (the object mask from the
measurements) and, for simulations, ``mask.occupancy`` (exact). A dataset of
several colour bands (``bands`` in ``dataset.json``: a colour camera's, or
narrow bands; ``physics/bands.py``) has the 16 channels of each band, named
``<band>.pol.<b1>.<b2>.<a2>``.
"""
from __future__ import annotations

import hashlib
import json
from collections import Counter
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..io.atomic import atomic_path
from ..io.exr import ExrFileError, read_channels, read_metadata
from ..physics import MEASUREMENTS
from ..physics.bands import BandError, BandSet, band_set_from_dict

FORMAT = "mi_nest.dataset"
# Version 2: simulated with the physical handedness of docs/physics.md (QWP angles are fast axes).
VERSION = 2
# Version 1 simulations used a QWP of the opposite handedness to the stress: their circular-input
# measurements show every stress with its sign flipped. Captures hold physical intensities either way.
OLD_HANDEDNESS_VERSION = 1
INDEX = "dataset.json"
CHANNELS = tuple(MEASUREMENTS)
MASK_CHANNELS = ("mask.dolp", "mask.occupancy")
UNITS = {"length": "mm", "stress": "MPa", "wavelength": "nm", "angle": "degree",
         "stress_optic_coefficient": "Brewster (1e-12 / Pa)", "intensity": "normalised (free space = 1)"}
# What a rerun must agree on to resume a dataset instead of starting a new one.
IDENTITY_KEYS = ("source", "resolution", "spp", "rotations", "camera_model", "polariscope", "bands")


class DatasetError(ValueError):
    """A dataset directory is missing, corrupt, incomplete or inconsistent."""


def measurement_channels(bands: BandSet | None) -> tuple[str, ...]:
    """The measurement channels of a dataset of ``bands`` (None: one band, the 16 as they are named)."""
    if bands is None:
        return CHANNELS
    return tuple(f"{band}.{name}" for band in bands.names for name in CHANNELS)


def measurement_of(channel: str) -> str:
    """The measurement (``pol.<b1>.<b2>.<a2>``) a channel holds, whichever band."""
    return channel[channel.index("pol."):]


def band_of(channel: str) -> str | None:
    """The band of a channel ``<band>.pol...``, or of a colour camera's analyser image ``<band>.analyzer.<angle>``
    (None for any other: a one-band dataset's ``pol...``, a monochrome camera's ``analyzer.<angle>``)."""
    for separator in (".pol.", ".analyzer."):
        band, found, _ = channel.partition(separator)
        if found:
            return band
    return None


def dataset_bands(index: dict) -> BandSet | None:
    """The bands a dataset was measured in (None: one wavelength, ``wavelength``)."""
    record = index.get("bands")
    if record is None:
        return None
    try:
        return band_set_from_dict(record)
    except BandError as error:
        raise DatasetError(f"{INDEX}: {error}; put the dataset's own dataset.json back, or simulate it again") \
            from None


def rotation_file(index: int) -> str:
    return f"rotations/{index:04d}.exr"


def write_index(directory: str | Path, index: dict) -> None:
    with atomic_path(Path(directory) / INDEX, ".json") as tmp:
        Path(tmp).write_text(json.dumps(index, indent=1, default=plain))


def plain(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot store {type(value).__name__} in {INDEX}")


def read_index(directory: str | Path) -> dict:
    path = Path(directory) / INDEX
    if not Path(directory).is_dir():
        raise DatasetError(f"dataset directory not found: {directory}")
    if not path.is_file():
        raise DatasetError(f"{directory} is not a dataset: no {INDEX}")
    try:
        index = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise DatasetError(f"{path}: corrupt ({error})") from error
    if not isinstance(index, dict) or index.get("format") != FORMAT:
        raise DatasetError(f"{path}: not an mi_nest dataset index (format is not '{FORMAT}')")
    version = index.get("version")
    simulated = isinstance(index.get("source"), dict) and index["source"].get("kind") == "simulated"
    if version == OLD_HANDEDNESS_VERSION and simulated:
        raise DatasetError(f"{path}: simulated before mi_nest fixed its QWP handedness (format version 1): its "
                           "circular-polariscope measurements show the stress with its sign flipped; simulate it "
                           "again into a new directory (mi-nest simulate SCENE -o NEW_DIRECTORY)")
    if version not in (OLD_HANDEDNESS_VERSION, VERSION):
        raise DatasetError(f"{path}: format version {version}, this mi_nest reads {VERSION}")
    missing = [k for k in ("resolution", "rotations", "channels", "wavelength", "complete") if k not in index]
    if missing:
        raise DatasetError(f"{path}: corrupt: missing {missing}")
    channels = index["channels"]
    expected = measurement_channels(dataset_bands(index))
    if not isinstance(channels, list) or sorted(map(str, channels)) != sorted(expected):
        listed = Counter(map(str, channels)) if isinstance(channels, list) else Counter()
        absent = [name for name in expected if name not in listed]
        foreign = [name for name in listed if name not in expected]
        repeated = [name for name, count in listed.items() if count > 1]
        wrong = [text for names, text in ((absent, f"without {absent}"), (foreign, f"{foreign} besides"),
                                          (repeated, f"{repeated} more than once")) if names]
        what = "pol.<b1>.<b2>.<a2>" if len(expected) == len(CHANNELS) else "<band>.pol.<b1>.<b2>.<a2>"
        raise DatasetError(f"{path}: corrupt: 'channels' must list each of the {len(expected)} measurements "
                           f"({what}) once; it lists {sum(listed.values())}, {', '.join(wrong)}: put "
                           "the dataset's own dataset.json back, or simulate or acquire it again")
    for rotation in index["rotations"]:
        if not {"index", "azimuth", "elevation", "file", "split", "to_world"} <= set(rotation):
            raise DatasetError(f"{path}: corrupt rotation entry {rotation}")
    for key, what in (("index", "rotation"), ("file", "rotation file")):
        counts = Counter(str(rotation[key]) for rotation in index["rotations"])
        repeated = [value for value, count in counts.items() if count > 1]
        if repeated:
            raise DatasetError(f"{path}: {what} {repeated[0]} is listed {counts[repeated[0]]} times (a dataset "
                               "lists each rotation once; an edited or merged dataset.json?): put the dataset's own "
                               "dataset.json back, or simulate or acquire it again")
    return index


# Header keys of a rotation file that tie it to its entry in dataset.json.
ROTATION_KEY, AZIMUTH_KEY, ELEVATION_KEY = "mi_nest.rotation", "mi_nest.azimuth", "mi_nest.elevation"
POSE_KEY, SETTINGS_KEY = "mi_nest.to_world", "mi_nest.settings"
# Largest difference (degrees, pose matrix entries) between a header and dataset.json that is rounding.
HEADER_TOLERANCE = 1e-6


def file_digests(files: Iterable[str | Path]) -> dict[str, str]:
    """``{path: short SHA-256 of its bytes}``: what a simulation's scene files held (``source.scene_content``)."""
    digests = {}
    for file in files:
        digest = hashlib.sha256()
        with open(file, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
        digests[str(file)] = digest.hexdigest()[:16]
    return digests


def content_fingerprint(directory: str | Path, index: dict) -> str:
    """A short hash of a dataset as it stands: its index and each rotation file's size and modification time.
    A dataset replaced or rewritten gets another; reading it leaves it as it is."""
    digest = hashlib.sha256(json.dumps(index, sort_keys=True, default=plain).encode())
    for entry in index["rotations"]:
        try:
            stat = (Path(directory) / entry["file"]).stat()
            digest.update(f"{entry['file']} {stat.st_size} {stat.st_mtime_ns}\n".encode())
        except FileNotFoundError:
            digest.update(f"{entry['file']} missing\n".encode())
    return digest.hexdigest()[:16]


def settings_fingerprint(index: dict) -> str:
    """A short hash of what every rotation file of a dataset shares: camera, sampling, polariscope, source."""
    source = index.get("source") or {}
    shared = {key: index.get(key) for key in ("resolution", "spp", "camera_model", "polariscope")}
    if index.get("bands") is not None:      # one-band datasets keep the fingerprint they had before bands
        shared["bands"] = index["bands"]
    shared["source"] = {key: source.get(key) for key in ("kind", "scene", "defines")}
    if "scene_content" in source:       # datasets simulated before it was recorded keep their fingerprint
        shared["source"]["scene_content"] = source["scene_content"]
    return hashlib.sha256(json.dumps(shared, sort_keys=True, default=plain).encode()).hexdigest()[:16]


def rotation_header(entry: dict, index: dict) -> dict[str, Any]:
    """The header attributes that name a rotation file's rotation, pose and dataset settings."""
    return {ROTATION_KEY: entry["index"], AZIMUTH_KEY: entry["azimuth"], ELEVATION_KEY: entry["elevation"],
            POSE_KEY: json.dumps(entry["to_world"], default=plain), SETTINGS_KEY: settings_fingerprint(index)}


def header_mismatch(header: dict[str, str], entry: dict, index: dict) -> str | None:
    """What in a rotation file's ``header`` contradicts its ``entry`` in dataset.json; None if nothing does.

    The rotation index is required (every mi_nest rotation file has it); pose and settings are compared
    where the file records them (files of older captures do not).
    """
    if ROTATION_KEY not in header:
        return "its header names no rotation (not written by mi_nest?)"
    if header[ROTATION_KEY] != str(entry["index"]):
        return f"its header says rotation {header[ROTATION_KEY]}, dataset.json lists it as rotation {entry['index']}"
    for key, name in ((AZIMUTH_KEY, "azimuth"), (ELEVATION_KEY, "elevation")):
        if key in header and not abs(float(header[key]) - entry[name]) <= HEADER_TOLERANCE:
            return f"its header says {name} {header[key]} deg, dataset.json {entry[name]} deg"
    if POSE_KEY in header and not np.allclose(json.loads(header[POSE_KEY]), entry["to_world"], rtol=0,
                                              atol=HEADER_TOLERANCE):
        return "its camera pose (to_world) differs from dataset.json's"
    if SETTINGS_KEY in header and header[SETTINGS_KEY] != settings_fingerprint(index):
        return "it was made with other settings (camera, resolution, spp, polariscope or scene) than dataset.json's"
    return None


def read_rotation(directory: str | Path, entry: dict, index: dict) -> dict[str, np.ndarray]:
    """``{name: (H, W)}`` of one rotation file, read whole and checked against its entry in dataset.json.

    Raises :class:`DatasetError` when the file cannot be read (a write cut short leaves a truncated file)
    or belongs to another rotation or dataset.
    """
    path = Path(directory) / entry["file"]
    try:
        images = read_channels(path)
        header = read_metadata(path)
    except ExrFileError as error:
        raise DatasetError(f"rotation {entry['index']}: {error}") from error
    problem = header_mismatch(header, entry, index)
    if problem is not None:
        raise DatasetError(f"{path}: {problem}; the file belongs to another rotation or dataset (swapped or "
                           "copied?): put the right file back, or simulate or acquire the dataset again")
    return images


def rotation_is_whole(directory: str | Path, entry: dict, index: dict) -> bool:
    """Whether ``entry``'s rotation file is on disk, readable to its end and its own: a rerun keeps it."""
    try:
        read_rotation(directory, entry, index)
    except DatasetError:
        return False
    return True


# A view counts as saturated when more than this share of its specimen's measurements sit at full scale.
SATURATED_SHARE = 0.05
# Full scale of the raw Mono12 frames a captured dataset's camera delivers (rig/genicam.py), in counts.
MONO12_FULL_SCALE = 4095


def full_scale(index: dict) -> float | None:
    """The normalised intensity the dataset's camera clips at; None when it does not clip (float renders)."""
    camera = index.get("camera_model") or {}
    if "white_level" in camera:
        return MONO12_FULL_SCALE / camera["white_level"]
    if camera.get("bits") is not None:
        return camera.get("saturation", 1.0)
    return None


def check_measurements(measured: np.ndarray, channels: Sequence[str], where: str) -> None:
    """Raise :class:`DatasetError` for NaN or inf in ``measured`` (H, W, C), or a view where all are zero."""
    finite = np.isfinite(measured)
    if not finite.all():
        counts = (~finite).sum(axis=(0, 1))
        listing = ", ".join(f"{name} ({count} pixels)" for name, count in zip(channels, counts) if count)
        raise DatasetError(f"{where}: NaN or inf in channel(s) {listing}; a broken capture or export: "
                           "capture or simulate this rotation again")
    if not measured.any():
        raise DatasetError(f"{where}: every measurement is zero (no light reached the camera: shutter, "
                           "exposure or light source?); capture this rotation again")
