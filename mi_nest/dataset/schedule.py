"""Which specimen rotations a dataset holds, and where the polariscope sits for each.

The specimen is fixed in the world (docs/physics.md section 1): rotating it by
``R = R_up(azimuth) R_right(elevation)`` about its centre is rendered as rotating
the whole polariscope by ``R^-1``. ``up`` and ``right`` are the reference
camera's image axes, so azimuth turns the specimen about the image's vertical and
elevation tips it towards the camera.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Rotation:
    index: int
    azimuth: float      # degrees, specimen yaw about the reference camera's up axis
    elevation: float    # degrees, specimen pitch about the reference camera's right axis
    split: str          # "train" or "test"


@dataclass(frozen=True)
class RotationSchedule:
    """The rotations of a dataset, simulated or captured: an azimuth x elevation grid (:func:`rotation_grid`)
    with a seeded share held out for testing."""
    azimuths: int = 32
    elevations: int = 32
    azimuth_range: float = 180.0     # degrees
    elevation_range: float = 180.0   # degrees
    test_fraction: float = 0.2       # held out for evaluation (the paper: 80 of 400)
    split_seed: int = 0

    def rotations(self) -> list[Rotation]:
        return rotation_grid(self.azimuths, self.elevations, self.azimuth_range, self.elevation_range,
                             self.test_fraction, self.split_seed)


def angles(count: int, span: float) -> list[float]:
    """``count`` angles (degrees) centred on 0 over ``span``: cell centres, so 180 degrees
    never holds both a view and its reverse."""
    if count < 1:
        raise ValueError(f"rotation count must be at least 1, got {count}")
    if not (0.0 <= span <= 360.0):
        raise ValueError(f"rotation range must be within [0, 360] degrees, got {span}")
    return [-0.5 * span + span * (i + 0.5) / count for i in range(count)]


def rotation_grid(azimuths: int, elevations: int, azimuth_range: float, elevation_range: float,
                  test_fraction: float = 0.2, seed: int = 0) -> list[Rotation]:
    """Every (azimuth, elevation) pair, elevation fastest; a seeded ``test_fraction`` held out."""
    pairs = [(a, e) for a in angles(azimuths, azimuth_range) for e in angles(elevations, elevation_range)]
    if not (0.0 <= test_fraction < 1.0):
        raise ValueError(f"test fraction must be in [0, 1), got {test_fraction}")
    held_out = round(test_fraction * len(pairs))
    test = set(np.random.default_rng(seed).choice(len(pairs), size=held_out, replace=False).tolist())
    return [Rotation(i, a, e, "test" if i in test else "train") for i, (a, e) in enumerate(pairs)]


def axis_rotation(axis: Sequence[float] | np.ndarray, degrees: float) -> np.ndarray:
    """3x3 rotation by ``degrees`` about the unit ``axis`` (right-handed)."""
    x, y, z = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def specimen_rotation(rotation: Rotation, right: np.ndarray, up: np.ndarray) -> np.ndarray:
    return axis_rotation(up, rotation.azimuth) @ axis_rotation(right, rotation.elevation)


def camera_to_world(reference: np.ndarray, rotation: Rotation, center: Sequence[float] | np.ndarray) -> np.ndarray:
    """The camera's 4x4 ``to_world`` when the specimen is turned by ``rotation`` about ``center``."""
    reference = np.asarray(reference, dtype=np.float64)
    right, up = reference[:3, 0], reference[:3, 1]
    inverse = specimen_rotation(rotation, right, up).T
    about_center = np.eye(4)
    about_center[:3, :3] = inverse
    about_center[:3, 3] = np.asarray(center) - inverse @ np.asarray(center)
    return about_center @ reference
