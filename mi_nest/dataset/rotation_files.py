"""How a simulated dataset's rotations are rendered and stored, and one rotation's render and file, wherever it
runs (this process, ``simulate.py``, or a Dask worker, ``sharded.py``)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mitsuba as mi
import numpy as np

from ..io.exr import write_channels
from ..render import render, render_bands
from ..scene import pose
from ..arguments import whole_number
from ..physics.bands import BandSet, parse_bands
from . import format as fmt
from .camera import CameraModel, bayer_sites
from .masks import banded_dolp_mask
from .schedule import RotationSchedule

@dataclass(frozen=True)
class SimulationSettings(RotationSchedule):
    """The rotations of a simulated dataset and how each is rendered, captured and stored."""
    res: int | None = None           # the scene's $res; None keeps the scene's own
    spp: int | None = None
    camera: CameraModel = field(default_factory=CameraModel)
    dolp_threshold: float = 0.95
    half: bool = True                # half-float EXR channels
    # A colour camera's bands, or narrow ones (physics/bands.py; a text such as 'rgb' is read under the scene's
    # light); None: the scene camera's (one band for a monochrome camera).
    bands: BandSet | str | None = None

    def __post_init__(self):
        # Checked before anything is written: 0 must not stand for the scene's own sample count.
        for name in ("azimuths", "elevations", "res", "spp"):
            if getattr(self, name) is not None:
                whole_number(name, getattr(self, name))
        if self.bands is not None:
            # Refused before anything starts: bands no camera has, or other than three under the colour filters.
            bands = parse_bands(self.bands) if isinstance(self.bands, str) else self.bands
            if self.camera.mosaic:
                bayer_sites(bands)


# Rotation file header keys of the render's fringe-aliasing report (simulated datasets).
ALIASED_KEY, DENSEST_KEY = "mi_nest.aliased_fraction", "mi_nest.densest_fringes"
BEAT_ALIASED_KEY, BEAT_DENSEST_KEY = "mi_nest.beat_aliased_fraction", "mi_nest.beat_densest_fringes"


@dataclass(frozen=True)
class RotationJob:
    """What rendering and writing a dataset's rotations needs, by value and by file: wherever it runs, the scene
    is loaded from ``scene_file`` there (Mitsuba objects do not travel)."""
    scene_file: str
    defines: dict
    output: Path
    settings: SimulationSettings     # its bands resolved
    index: dict                      # dataset.json without its rotations: what a rotation file's header records
    variant: str                     # the Mitsuba variant the run is on, which its workers take too


def render_rotation(scene: mi.Scene, entry: dict, settings: SimulationSettings):
    """The render of rotation ``entry`` of ``scene`` (turned to its pose): one band, or each of ``settings.bands``."""
    pose(scene, entry["to_world"])
    return (render(scene, spp=settings.spp) if settings.bands is None
            else render_bands(scene, settings.bands, spp=settings.spp))


def write_rotation(path, rendered, entry, index, settings, aliasing=None, beat=None):
    """The rotation file of ``entry`` from its render's channels: the camera model (seeded by the rotation), the
    masks, the header (with the render's ``aliasing`` report and, for bands, its ``beat``'s), one atomic EXR."""
    measured = settings.camera.capture({name: rendered[name] for name in index["channels"]}, entry["index"],
                                       settings.bands)
    channels = dict(measured)
    channels["mask.dolp"] = banded_dolp_mask(measured, None if settings.bands is None else settings.bands.names,
                                             settings.dolp_threshold).astype(np.float32)
    channels["mask.occupancy"] = (rendered["path.length"] > 0).astype(np.float32)
    metadata = fmt.rotation_header(entry, index)
    if aliasing is not None:
        metadata.update({ALIASED_KEY: f"{aliasing.fraction:.6g}", DENSEST_KEY: f"{aliasing.densest:.6g}"})
    if beat is not None:
        metadata.update({BEAT_ALIASED_KEY: f"{beat.fraction:.6g}", BEAT_DENSEST_KEY: f"{beat.densest:.6g}"})
    write_channels(path, channels, half=settings.half, metadata=metadata)
