"""The on-disk dataset: ``dataset.json`` plus one multichannel EXR per rotation.

The same format holds simulations and real captures (``source.kind``). Each
rotation's EXR has the 16 ``pol.<b1>.<b2>.<a2>`` channels (normalised
intensities, half float, ZIP), ``mask.dolp`` (the object mask from the
measurements) and, for simulations, ``mask.occupancy`` (exact).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_path
from ..physics import MEASUREMENTS

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
IDENTITY_KEYS = ("source", "resolution", "spp", "rotations", "camera_model", "polariscope")


class DatasetError(ValueError):
    """A dataset directory is missing, corrupt, incomplete or inconsistent."""


def rotation_file(index):
    return f"rotations/{index:04d}.exr"


def write_index(directory, index: dict):
    with atomic_path(Path(directory) / INDEX, ".json") as tmp:
        Path(tmp).write_text(json.dumps(index, indent=1, default=plain))


def plain(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot store {type(value).__name__} in {INDEX}")


def read_index(directory) -> dict:
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
    for rotation in index["rotations"]:
        if not {"index", "azimuth", "elevation", "file", "split", "to_world"} <= set(rotation):
            raise DatasetError(f"{path}: corrupt rotation entry {rotation}")
    return index
