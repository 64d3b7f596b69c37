"""One truth: the scene a simulated dataset was rendered from, against which everything made from it is scored.

A dataset records its scene file and ``-D`` defines. A reconstruction, its
error metrics and its views use the scene they are given for the specimens'
geometry, material and camera; the field they are compared with is always
the recorded one, and a given scene that differs from the record is named,
value by value, in a warning (or refused when its specimens are elsewhere).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import mitsuba as mi
import numpy as np

from ..scene import SceneError, load_scene, scene_defaults, scene_field, scene_origin, specimen_bounds, specimen_shapes

# Defines that set how the camera samples the images, not the specimen or its stress: the images' size is
# checked against the film where rays are made, so they need not match the record.
SAMPLING_DEFINES = frozenset({"res", "spp"})
# Specimens farther apart than this share of their size are another part, not the same one.
BOUNDS_TOLERANCE = 1e-3


@dataclass(frozen=True)
class SceneRecord:
    """A scene file and the defines it was loaded with."""
    file: Path
    defines: dict[str, str] = field(default_factory=dict)

    @classmethod
    def of(cls, scene: mi.Scene) -> SceneRecord | None:
        """What :func:`~mi_nest.scene.load_scene` loaded ``scene`` from (None for a scene made otherwise)."""
        origin = scene_origin(scene)
        return None if origin is None else cls(Path(origin[0]).resolve(), _as_text(origin[1]))

    def values(self) -> dict[str, str]:
        """Every ``$NAME`` the scene file declares a default for, as the defines set it."""
        return {**scene_defaults(self.file), **self.defines}

    def differences(self, other: SceneRecord) -> list[str]:
        """What differs between this scene and ``other``'s, beside their sampling: ``'NAME VALUE vs VALUE'``."""
        if self.file != other.file:
            return [f"file {self.file} vs {other.file}"]
        ours, theirs = self.values(), other.values()
        return [f"{name} {ours.get(name, 'unset')} vs {theirs.get(name, 'unset')}"
                for name in sorted((set(ours) | set(theirs)) - SAMPLING_DEFINES)
                if not _same_value(ours.get(name), theirs.get(name))]

    def load(self, **overrides) -> mi.Scene:
        return load_scene(self.file, **{**self.defines, **overrides})


def recorded_scene(source: dict) -> SceneRecord | None:
    """The scene a simulated dataset's ``source`` (in its ``dataset.json``) records; None for captures."""
    if source.get("kind") != "simulated" or not source.get("scene"):
        return None
    return SceneRecord(Path(source["scene"]).resolve(), _as_text(source.get("defines") or {}))


def recorded_truth(dataset):
    """``(scene, field)``: the scene a simulated ``dataset`` was rendered from, loaded as its ``dataset.json``
    records it, and that scene's stress field (:func:`~mi_nest.scene.scene_field`), what reconstructions from it
    are scored against. Refused for a capture (no record)."""
    record = recorded_scene(dataset.index.get("source") or {})
    if record is None:
        raise SceneError(f"{dataset.directory} records no simulated scene (a capture): it has no true field")
    scene = record.load()
    return scene, scene_field(scene)


def truth_scene(scene: mi.Scene, source: dict, what: str) -> mi.Scene:
    """The scene whose field a simulated dataset (``source``, as its ``dataset.json`` records it) was rendered from:
    ``scene`` itself when it was loaded as the record says, else the record loaded again, with a warning
    that names each value that differs. ``what`` names the dataset in messages.

    Refused when the given scene's specimens are not where the record's are: the images would then be
    of another part than the rays are traced through.
    """
    record = recorded_scene(source)
    if record is None:
        return scene
    given = SceneRecord.of(scene)
    differences = ["a scene not loaded by mi_nest.load_scene"] if given is None else given.differences(record)
    if not differences:
        return scene
    if not record.file.is_file():
        raise SceneError(f"{what} was simulated from {record.file}, which is gone: its true field cannot be "
                         "loaded to score against; put the scene back, or pass truth=None (--no-truth) to skip "
                         "the ground-truth errors")
    recorded = record.load(**{k: v for k, v in (given.defines if given else {}).items() if k in SAMPLING_DEFINES})
    _require_same_specimens(scene, recorded, what)
    warnings.warn(f"the scene given differs from the one {what} was simulated from ({'; '.join(differences)}: "
                  f"given vs recorded); its geometry, material and camera are used, and errors are measured "
                  f"against the recorded field ({record.file.name} with {_defines_text(record.defines)}). Load "
                  f"the scene with the dataset's defines to silence this", RuntimeWarning, stacklevel=3)
    return recorded


def _require_same_specimens(given, recorded, what):
    given_low, given_high = specimen_bounds(specimen_shapes(given))
    low, high = specimen_bounds(specimen_shapes(recorded))
    size = float(np.max(high - low))
    if max(np.max(np.abs(given_low - low)), np.max(np.abs(given_high - high))) > BOUNDS_TOLERANCE * size:
        raise SceneError(f"the scene given holds its specimens from {_point(given_low)} to {_point(given_high)} "
                         f"mm, the one {what} was simulated from from {_point(low)} to {_point(high)} mm: "
                         "reconstruct with the dataset's scene and defines")


def _same_value(a, b) -> bool:
    if a is None or b is None:
        return a == b
    try:
        numbers_a = [float(x) for x in a.replace(",", " ").split()]
        numbers_b = [float(x) for x in b.replace(",", " ").split()]
    except ValueError:
        return a.strip() == b.strip()
    return len(numbers_a) == len(numbers_b) and all(math.isclose(x, y, rel_tol=1e-9, abs_tol=1e-12)
                                                    for x, y in zip(numbers_a, numbers_b))


def _as_text(defines: dict) -> dict[str, str]:
    return {str(k): str(v) for k, v in defines.items()}


def _defines_text(defines: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in sorted(defines.items())) or "its defaults"


def _point(values) -> str:
    return "(" + ", ".join(f"{x:.3g}" for x in values) + ")"
