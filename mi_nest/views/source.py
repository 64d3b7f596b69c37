"""What a view looks at: a scene's own (true) field, or a reconstruction's field in its scene's specimens."""
from __future__ import annotations

from dataclasses import dataclass, field as dataclass_field
from pathlib import Path

import mitsuba as mi
import numpy as np

from ..dataset.truth import recorded_scene, truth_scene
from ..fields import StressField
from ..reconstruct import Reconstruction
from ..reconstruct.trust import READ_ERRORS, TRUST_FILE, TrustMap
from ..scene import load_scene, reference_pose, specimen_bounds, specimen_shapes
from ..separation import FULL_FILE, RECORD_FILE

RESULT_FILES = ("reconstruction.json", "field.npz")
SEPARATION_FILES = (RECORD_FILE, FULL_FILE)


@dataclass
class ViewSource:
    """A scene and the field to show in its specimens: ``field`` None is the scene's own stress. Views turn the
    specimen about ``center`` from the camera's pose as loaded, ``reference``. A reconstruction's ``trust`` is its
    trust map (``trust.npz``; None where the run wrote none). ``full``: the field is a separation's full stress
    (``mi-nest separate``), of a reconstruction's deviator or a scene's."""
    scene: mi.Scene
    field: StressField | None
    name: str
    reconstruction: Reconstruction | None = None
    trust: TrustMap | None = None
    full: bool = False
    reference: np.ndarray = dataclass_field(init=False, repr=False)
    center: np.ndarray = dataclass_field(init=False, repr=False)

    def __post_init__(self):
        self.reference = reference_pose(self.scene)
        low, high = specimen_bounds(specimen_shapes(self.scene))
        self.center = 0.5 * (low + high)

    @property
    def is_reconstruction(self) -> bool:
        return self.reconstruction is not None

    @property
    def deviatoric(self) -> bool:
        """Whether the field is trace-free: a reconstruction's, unless its mean stress was separated."""
        return self.is_reconstruction and not self.full

    def truth(self) -> ViewSource | None:
        """The scene a reconstruction's simulated dataset was rendered from, with its own stress: the truth the
        reconstruction is compared with (None for a scene itself, or for a reconstruction of captured data). A
        separation of a scene's own field has that scene for its truth."""
        if self.reconstruction is None:
            return ViewSource(self.scene, None, f"truth of {self.name}") if self.full else None
        dataset_source = self.reconstruction.source.get("dataset_source", {})
        if recorded_scene(dataset_source) is None:
            return None
        truth = ViewSource(truth_scene(self.scene, dataset_source, f"the dataset of {self.name}"), None,
                           f"truth of {self.name}")
        truth.reference, truth.center = self.reference, self.center     # the scene's camera may have moved since
        return truth


def open_source(text: str | Path, defines: dict | None = None) -> ViewSource:
    """A scene (XML file or shipped name, with ``defines``), a result directory of ``mi-nest reconstruct``
    (its field in the scene it was reconstructed with, ``defines`` added to that scene's) or of ``mi-nest
    separate`` (the full stress in the scene of what was separated)."""
    path = Path(text)
    if path.is_dir() and all((path / name).exists() for name in SEPARATION_FILES):
        return _separation(path, defines)
    if path.is_dir() and any((path / name).exists() for name in RESULT_FILES):
        reconstruction = Reconstruction.load(path)
        scene_file, scene_defines = _reconstruction_scene(path, reconstruction.source)
        scene = load_scene(scene_file, **{**scene_defines, **dict(defines or {})})
        return ViewSource(scene, reconstruction.field, str(path), reconstruction, _trust(path))
    if path.is_dir():
        raise ValueError(f"{path} is a directory but not a reconstruction (no {' or '.join(RESULT_FILES)}): "
                         "give a scene or the output directory of mi-nest reconstruct")
    return ViewSource(load_scene(path, **dict(defines or {})), None, str(path))


def _separation(path: Path, defines: dict | None) -> ViewSource:
    import json

    from ..fields.grid import GridField
    from ..io.grid import load_stress_grid
    try:
        record = json.loads((path / RECORD_FILE).read_text())
        separated = record["source"]
    except (ValueError, KeyError, OSError) as error:
        raise ValueError(f"{path / RECORD_FILE} cannot be read ({error}): run mi-nest separate again") from None
    base = open_source(separated, {**record.get("defines", {}), **dict(defines or {})})
    return ViewSource(base.scene, GridField(load_stress_grid(path / FULL_FILE)), str(path), base.reconstruction,
                      base.trust, full=True)


def _reconstruction_scene(path: Path, source: dict) -> tuple[str, dict]:
    if "scene_file" in source:
        return source["scene_file"], source.get("defines", {})
    dataset = source.get("dataset_source", {})
    if "scene" not in dataset:
        raise ValueError(f"{path}/reconstruction.json does not record its scene (made before mi_nest recorded "
                         "it): reconstruct again")
    return dataset["scene"], dataset.get("defines", {})


def _trust(path: Path) -> TrustMap | None:
    if not (path / TRUST_FILE).is_file():
        return None
    try:
        return TrustMap.load(path / TRUST_FILE)
    except READ_ERRORS as error:
        raise ValueError(f"{path / TRUST_FILE} is damaged and cannot be read ({error}); delete it to go on without "
                         "the trust map, or run the mi-nest reconstruct command that wrote it again") from error
