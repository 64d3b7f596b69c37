"""Render a multi-axis polariscope dataset of a scene: every specimen rotation, all 16 channels.

One Jones pass per ray gives all 16 measurements of a rotation (the integrator
writes them as channels). The camera model, the masks and the EXR of each
rotation are made on a writer thread while the next rotation renders, through a
bounded queue. Every file is written atomically, and a rerun with the same
settings resumes: finished rotations are kept, not redone.
"""
from __future__ import annotations

import json
import queue
import shutil
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any
from pathlib import Path

import mitsuba as mi
import numpy as np

from ..cluster import Cluster, ClusterConfig, cluster_for
from ..io.exr import read_channels, read_metadata
from ..io.lock import locked_directory, other_entries
from ..physics.aliasing import ALIASED_FRACTION
from ..physics.polariscope import ANALYZERS, INPUT_QWP_SETTINGS, OUTPUT_QWP_SETTINGS
from ..physics.bands import parse_bands
from ..render import available_memory, render_plan, scene_bands, scene_light
from ..scene import (SceneError, camera_of, load_scene, polariscope_camera, polariscope_light, reference_pose,
                     scene_file, scene_inputs, scene_sensor, specimen_bounds, specimen_media, specimen_shapes)
from ..version import __version__
from . import format as fmt
from .masks import agreement
from .rotation_files import (ALIASED_KEY, BEAT_ALIASED_KEY, BEAT_DENSEST_KEY, DENSEST_KEY, RotationJob,
                             SimulationSettings, render_rotation, write_rotation)
from .schedule import camera_to_world


@dataclass
class SimulationReport:
    directory: Path
    rendered: int
    kept: int
    render_seconds: float
    write_seconds: float             # on the writer thread, beside the renders
    mask_iou: float                  # mean over rotations, DoLP mask against the exact occupancy
    warnings: list = field(default_factory=list)
    wall_seconds: float = 0.0        # the rotations' loop, renders and writing overlapped

    def describe(self) -> str:
        per = self.rendered or 1
        return (f"{self.rendered} rotations rendered, {self.kept} kept from an earlier run in "
                f"{self.wall_seconds:.2f} s; render {self.render_seconds:.2f} s "
                f"({self.render_seconds / per * 1e3:.1f} ms each), noise, masks "
                f"and writing {self.write_seconds:.2f} s ({self.write_seconds / per * 1e3:.1f} ms each) beside "
                f"them; DoLP mask against the exact occupancy: mean IoU {self.mask_iou:.3f}")


# Memory one rotation takes in a dataset's index: 4.4 kB measured at the peak of writing dataset.json, doubled for
# the index read back when a run resumes.
INDEX_BYTES_PER_ROTATION = 8 * 1024


def _require_room(settings, resolution, output):
    """Refuse a dataset whose index would not fit in memory, or whose rotation files (uncompressed, the most ZIP
    can leave) would not fit on the disk of ``output``; before the rotations are listed, which alone can
    exhaust memory."""
    rotations = settings.azimuths * settings.elevations
    count = f"{rotations} rotations ({settings.azimuths} azimuths x {settings.elevations} elevations)"
    available = available_memory()
    if available is not None and rotations * INDEX_BYTES_PER_ROTATION > available:
        raise fmt.DatasetError(f"a dataset of {count} needs about {rotations * INDEX_BYTES_PER_ROTATION / 2**30:.3g} "
                               f"GiB of memory for its index alone; {available / 2**30:.3g} GiB are available: "
                               "simulate fewer rotations (--azimuth, --elevation)")
    width, height = resolution
    channel_bytes = 2 if settings.half else 4
    per_rotation = width * height * (len(fmt.measurement_channels(settings.bands)) + len(fmt.MASK_CHANNELS)) \
        * channel_bytes
    written = sum(file.stat().st_size for file in (output / "rotations").glob("*.exr"))
    free = shutil.disk_usage(output).free
    if rotations * per_rotation - written > free:
        raise fmt.DatasetError(f"a dataset of {count} of {width}x{height} pixels needs up to "
                               f"{(rotations * per_rotation - written) / 2**30:.3g} GiB more on disk "
                               f"({per_rotation / 2**20:.3g} MiB per rotation file before compression); "
                               f"{free / 2**30:.3g} GiB are free where {output} is: simulate fewer rotations "
                               "(--azimuth, --elevation) or a lower resolution (--res)")


# Rendered rotations that may wait for the writers: each holds a render's channels (about 7 MB at 256 x 256).
WRITE_QUEUE = 4
# Writer threads: NumPy's noise and OpenEXR's compression run beside the renders and beside each other.
WRITERS = 2


class _RotationWriter:
    """The camera model, the masks and the EXR of each rendered rotation, on threads of their own.

    :meth:`put` waits while :data:`WRITE_QUEUE` rotations are queued (memory stays
    bounded) and raises a writer's error, if one had one; :meth:`written` says
    which rotations are on disk since it was last asked; :meth:`finish` writes
    what is queued (an interrupted run keeps every rotation it rendered).
    """

    def __init__(self, settings, index, threads: int = WRITERS):
        self.settings, self.index = settings, index
        self._queue = queue.Queue(maxsize=WRITE_QUEUE)
        self._done = queue.Queue()
        self._error = None
        self._threads = [threading.Thread(target=self._run, name=f"mi_nest-simulate-writer-{i}", daemon=True)
                         for i in range(threads)]
        for thread in self._threads:
            thread.start()

    def put(self, path, channels, entry, aliasing, beat=None) -> None:
        while True:
            self._raise_error()
            try:
                self._queue.put((path, channels, entry, aliasing, beat), timeout=0.1)
                return
            except queue.Full:
                continue

    def written(self) -> list[tuple[dict, float]]:
        done = []
        while True:
            try:
                done.append(self._done.get_nowait())
            except queue.Empty:
                return done

    def finish(self, raise_error: bool = True) -> None:
        for thread in self._threads:
            if thread.is_alive():
                self._queue.put(None)
        for thread in self._threads:
            thread.join()
        if raise_error:
            self._raise_error()

    def _run(self):
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self._error is not None:
                continue        # drain: the run is ending with the error
            path, channels, entry, aliasing, beat = item
            start = time.perf_counter()
            try:
                write_rotation(path, channels, entry, self.index, self.settings, aliasing, beat)
            except BaseException as error:      # raised in the main thread, at its next put or at finish
                self._error = error
                continue
            self._done.put((entry, time.perf_counter() - start))

    def _raise_error(self):
        if self._error is not None:
            raise self._error


def dataset_index(scene: mi.Scene, source: str | Path, defines: dict, settings: SimulationSettings) -> dict:
    """The ``dataset.json`` of ``settings``' rotations of ``scene`` (loaded from ``source`` with ``defines``),
    before any rotation is on disk; acquisitions start from it too."""
    shapes = specimen_shapes(scene)
    low, high = specimen_bounds(shapes)
    center = 0.5 * (low + high)
    media = specimen_media(scene)
    sensor = polariscope_camera(scene)
    light = polariscope_light(scene)
    reference = reference_pose(scene)
    return {
        "format": fmt.FORMAT, "version": fmt.VERSION, "complete": False,
        "software": {"mi_nest": __version__, "mitsuba": mi.__version__},
        "source": {"kind": "simulated", "scene": str(scene_file(source)), "defines": dict(defines),
                   "scene_content": fmt.file_digests(scene_inputs(source, **defines))},
        "units": fmt.UNITS,
        "resolution": [int(n) for n in sensor.film().size()],
        "spp": int(settings.spp or sensor.sampler().sample_count()),
        "camera": {"projection": camera_of(scene).class_name(), "reference_to_world": reference.tolist()},
        "specimen_center": center.tolist(),
        "wavelength": sorted({m.wavelength for m in media}),
        "stress_optic_coefficient": sorted({m.stress_optic_coefficient for m in media}),
        "polariscope": {"polarizer": float(light.polarizer), "input_qwp": list(INPUT_QWP_SETTINGS),
                        "output_qwp": list(OUTPUT_QWP_SETTINGS), "analyzer": list(ANALYZERS)},
        "channels": list(fmt.measurement_channels(settings.bands)),
        "bands": None if settings.bands is None else settings.bands.to_dict(),
        "mask_channels": list(fmt.MASK_CHANNELS),
        "camera_model": settings.camera.to_dict(),
        "dolp_threshold": settings.dolp_threshold,
        "split": {"test_fraction": settings.test_fraction, "seed": settings.split_seed},
        "rotations": [{"index": r.index, "azimuth": r.azimuth, "elevation": r.elevation, "split": r.split,
                       "file": fmt.rotation_file(r.index),
                       "to_world": camera_to_world(reference, r, center).round(9).tolist()}
                      for r in settings.rotations()],
    }


def simulate(scene_file: str | Path, output: str | Path, settings: SimulationSettings = SimulationSettings(),
             defines: Mapping[str, Any] | Iterable[tuple[str, Any]] = (), progress: bool = True,
             on_rotation: Callable[[dict], None] | None = None, cluster: ClusterConfig | Cluster | None = None,
             ) -> SimulationReport:
    """Render the dataset of ``scene_file`` into ``output``; resume it if it was interrupted.

    ``on_rotation(entry)`` is called after each rotation is safely on disk. The
    run holds ``output``: a second writer gets a
    :class:`~mi_nest.io.lock.DirectoryInUseError`. With ``cluster`` (one to
    connect to for the run, or one connected already, ``mi_nest.cluster.connect``)
    the rotations are tasks on Dask workers (``dataset/sharded.py``); the
    channels are the same as in one process.
    """
    with locked_directory(output):
        return _simulate(scene_file, Path(output), settings, dict(defines), progress, on_rotation, cluster)


def _recorded_bands(settings, scene, scene_file):
    """The bands a simulation records: ``settings.bands`` (a text read under the scene panel's light), else the
    scene camera's. A monochrome camera under a light of several wavelengths is refused: which wavelengths its one
    channel weighs is its sensor's curve, which the scene does not give."""
    light = scene_light(scene)
    if isinstance(settings.bands, str):
        return parse_bands(settings.bands, light)
    bands = settings.bands if settings.bands is not None else scene_bands(scene)
    if bands is None and light is not None:
        raise SceneError(f"{scene_file}: the light panel's spectrum is {light.name} and the camera has no bands: give "
                         "the camera its bands (bands = rgb, narrow ones such as 450,532,650, or its curves; --bands), "
                         "or leave the light monochromatic")
    return bands


def _simulate(scene_file, output, settings, defines, progress, on_rotation, cluster):
    if settings.res is not None:
        defines["res"] = settings.res
    scene = load_scene(scene_file, **defines)
    settings = replace(settings, bands=_recorded_bands(settings, scene, scene_file))
    render_plan(scene, settings.spp)     # an image that cannot be rendered is refused before anything is written
    _require_room(settings, [int(n) for n in scene_sensor(scene).film().size()], output)
    index = dataset_index(scene, scene_file, defines, settings)
    if settings.res is not None and index["resolution"] != [settings.res, settings.res]:
        raise SceneError(f"{scene_file}: --res {settings.res} had no effect (the scene's film is "
                         f"{index['resolution']}); give the film width/height as $res")
    if (output / fmt.INDEX).exists():
        previous = fmt.read_index(output)
        # The index of a run that wrote no rotation (refused or failed at its first) holds nothing to resume.
        differing = [k for k in fmt.IDENTITY_KEYS if previous.get(k) != json_round_trip(index[k])] \
            if _holds_rotations(output, previous) else []
        _refuse_an_edited_scene(output, previous.get("source") or {}, index["source"], differing)
        if differing:
            raise fmt.DatasetError(f"{output} holds a dataset made with other settings ({', '.join(differing)}); "
                                   "choose a new directory or delete it")
    elif other_entries(output):
        raise fmt.DatasetError(f"{output} exists and is not an mi_nest dataset; choose an empty directory")

    whole = [fmt.rotation_is_whole(output, entry, index) for entry in index["rotations"]]
    kept = [entry for entry, done in zip(index["rotations"], whole) if done]
    todo = [entry for entry, done in zip(index["rotations"], whole) if not done]
    # The cluster is reached, and its workers checked, before the bar starts: a refusal is the run's one line.
    with cluster_for(cluster, bool(todo)) as connected:
        return _render_rotations(scene, scene_file, defines, output, index, settings, kept, todo, progress,
                                 on_rotation, connected)


def _render_rotations(scene, scene_file, defines, output, index, settings, kept, todo, progress, on_rotation,
                      cluster):
    """Render ``todo`` here or on ``cluster`` (a connected one, or None), count ``kept``, and complete the index."""
    from tqdm import tqdm
    bar = tqdm(total=len(index["rotations"]), desc="simulate", unit="rotation", disable=not progress)
    tally = _Tally()
    start = time.perf_counter()

    def on_disk(entry, rendered=True, render_seconds=0.0, write_seconds=0.0):
        tally.add(rendered, render_seconds, write_seconds)
        bar.update()
        if on_rotation is not None:
            on_rotation(entry)

    with warnings.catch_warnings(record=True) as caught, bar:    # the bar is closed however the loop ends
        warnings.simplefilter("always")
        for entry in kept:
            on_disk(entry, rendered=False)
        if cluster is None:
            _render_here(scene, output, index, settings, todo, on_disk)
        else:
            from .sharded import render_on_cluster
            fmt.write_index(output, index)
            job = RotationJob(str(scene_file), dict(defines), output, settings,
                              {k: v for k, v in index.items() if k != "rotations"}, mi.variant())
            render_on_cluster(cluster, job, todo, on_disk)
    wall_seconds = time.perf_counter() - start
    if caught:
        # One summary, not one warning per rotation.
        warnings.warn(f"{len(caught)} warning(s) over {tally.rendered} rendered rotations; the last: "
                      f"{caught[-1].message}", RuntimeWarning, stacklevel=2)
    ious = [agreement(*(m > 0.5 for m in read_channels(output / e["file"], list(fmt.MASK_CHANNELS)).values())).iou
            for e in index["rotations"]]
    index["complete"] = True
    index["mask_agreement"] = {"mean_iou": float(np.mean(ious)), "min_iou": float(np.min(ious))}
    index["fringe_aliasing"] = _aliasing_summary(output, index["rotations"])
    fmt.write_index(output, index)
    return SimulationReport(output, tally.rendered, tally.kept, tally.render_seconds, tally.write_seconds,
                            float(np.mean(ious)), [str(w.message) for w in caught], wall_seconds)


@dataclass
class _Tally:
    """Rotations rendered and kept so far, and the seconds their renders and writes took."""
    rendered: int = 0
    kept: int = 0
    render_seconds: float = 0.0
    write_seconds: float = 0.0

    def add(self, rendered: bool, render_seconds: float, write_seconds: float) -> None:
        self.rendered += rendered
        self.kept += not rendered
        self.render_seconds += render_seconds
        self.write_seconds += write_seconds


def _render_here(scene, output, index, settings, entries, on_disk):
    """Render ``entries`` in this process, writing on the writer threads beside the renders."""
    writer = _RotationWriter(settings, index)
    renders = {}

    def written():
        for entry, seconds in writer.written():
            on_disk(entry, True, renders.pop(entry["index"]), seconds)

    try:
        for number, entry in enumerate(entries):
            rendering = time.perf_counter()
            result = render_rotation(scene, entry, settings)
            renders[entry["index"]] = time.perf_counter() - rendering
            if not number:      # the index before the first rotation file: a render refused writes nothing
                fmt.write_index(output, index)
            writer.put(output / entry["file"], result.channels, entry, result.aliasing, result.beat)
            written()
    except BaseException:
        writer.finish(raise_error=False)    # what was rendered is written; the first error goes on
        raise
    writer.finish()
    written()


def _holds_rotations(output, index):
    """Whether any rotation file of ``index`` is in ``output``: what a rerun would resume."""
    return any((output / entry["file"]).exists() for entry in index["rotations"])


def _refuse_an_edited_scene(output, previous, source, differing):
    """Refuse to resume a dataset whose scene files changed since it was started: its rotations would show
    two scenes."""
    same_scene = {k: v for k, v in previous.items() if k != "scene_content"} == \
        json_round_trip({k: v for k, v in source.items() if k != "scene_content"})
    if differing != ["source"] or not same_scene:
        return
    if "scene_content" not in previous:
        raise fmt.DatasetError(f"{output} was started before mi_nest recorded the content of its scene's files, so "
                               "a rerun cannot tell whether they changed since; choose a new directory or delete it")
    edited = sorted(name for name in {*previous["scene_content"], *source["scene_content"]}
                    if previous["scene_content"].get(name) != source["scene_content"].get(name))
    raise fmt.DatasetError(f"{output} was simulated from {source['scene']} before {', '.join(edited)} changed; "
                           "resuming would mix rotations of two scenes: choose a new directory or delete it")


def _aliasing_summary(output, rotations):
    """How many views have fringes denser than their pixels, from each rotation file's render report."""
    reports = [read_metadata(output / e["file"]) for e in rotations]
    reports = [r for r in reports if ALIASED_KEY in r]
    if not reports:
        return None
    summary = _fractions_summary(reports, ALIASED_KEY, DENSEST_KEY)
    beats = [r for r in reports if BEAT_ALIASED_KEY in r]
    if len(beats) == len(reports):      # the slowest beat between the bands, where they are several
        summary["beat"] = _fractions_summary(beats, BEAT_ALIASED_KEY, BEAT_DENSEST_KEY)
    return summary


def _fractions_summary(reports, fraction_key, densest_key):
    fractions = [float(r[fraction_key]) for r in reports]
    return {"views": sum(f > ALIASED_FRACTION for f in fractions), "of": len(fractions),
            "mean_fraction": float(np.mean(fractions)), "max_fraction": max(fractions),
            "densest": max(float(r[densest_key]) for r in reports)}


def json_round_trip(value: Any) -> Any:
    return json.loads(json.dumps(value, default=fmt.plain))
