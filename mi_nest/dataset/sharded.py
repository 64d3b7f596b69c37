"""A dataset's rotations as tasks on a Dask cluster (``mi-nest simulate --scheduler``).

Each task renders one rotation and writes its file where the dataset lies, as one
process does (the same render, camera model seeded by the rotation, masks and
atomic EXR), so the channels are the same byte for byte. A worker loads the scene
from its file once and keeps it for the rotations it is given. A task first looks
whether its rotation is already whole on disk: a task the scheduler runs again
after its worker died once it had written renders nothing twice, and a run
interrupted however resumes from what is on disk.
"""
from __future__ import annotations

import json
import time
import uuid
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import mitsuba as mi

from .. import variants
from ..cluster import Cluster, ClusterError
from ..scene import load_scene
from . import format as fmt
from .rotation_files import RotationJob, render_rotation, write_rotation

# The scene a worker process last loaded, by file and defines: its rotations reuse it.
_loaded: dict = {}


@dataclass(frozen=True)
class RotationOutcome:
    """What a task did: whether it rendered (False: the file was whole already), its seconds and the warnings
    the render raised (re-raised where the run is watched)."""
    rendered: bool
    render_seconds: float = 0.0
    write_seconds: float = 0.0
    warnings: tuple[str, ...] = ()


def _scene(job: RotationJob):
    key = (job.scene_file, json.dumps(job.defines, sort_keys=True, default=str))
    if key not in _loaded:
        _loaded.clear()
        _loaded[key] = load_scene(job.scene_file, **job.defines)
    return _loaded[key]


def render_on_worker(job: RotationJob, entry: dict, drjit_threads: int | None) -> RotationOutcome:
    """On a worker: rotation ``entry`` rendered and written, unless its file is whole already."""
    if fmt.rotation_is_whole(job.output, entry, job.index):
        return RotationOutcome(rendered=False)
    if mi.variant() != job.variant:
        variants.use(job.variant)       # a remote worker started on another: refused there if it cannot run it
    if drjit_threads is not None:
        import drjit as dr
        dr.set_thread_count(drjit_threads)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        start = time.perf_counter()
        result = render_rotation(_scene(job), entry, job.settings)
        rendered = time.perf_counter()
        write_rotation(job.output / entry["file"], result.channels, entry, job.index, job.settings, result.aliasing,
                       result.beat)
    return RotationOutcome(True, rendered - start, time.perf_counter() - rendered,
                           tuple(str(w.message) for w in caught))


def render_on_cluster(cluster: Cluster, job: RotationJob, entries: list[dict],
                      on_disk: Callable[..., None]) -> None:
    """Render ``entries`` as tasks on ``cluster``; ``on_disk(entry, rendered, render_seconds, write_seconds)`` as
    each is written. The first task that fails cancels the rest and raises its error; what was written stays."""
    from distributed import KilledWorker, as_completed
    client = cluster.client
    [shared] = client.scatter([job], broadcast=True)
    run = uuid.uuid4().hex[:8]
    futures = {client.submit(render_on_worker, shared, entry, cluster.drjit_threads, pure=False,
                             key=f"mi_nest-rotation-{entry['index']}-{run}"): entry for entry in entries}
    try:
        for future in as_completed(futures):
            try:
                outcome = future.result()
            except KilledWorker as error:
                raise ClusterError(f"rotation {futures[future]['index']} was running on every worker that died "
                                   f"({error}); the rotations written are kept: find why the workers die (memory: "
                                   "fewer workers per machine), then run the same command again to resume") from None
            for message in outcome.warnings:
                warnings.warn(message, RuntimeWarning, stacklevel=2)
            on_disk(futures[future], outcome.rendered, outcome.render_seconds, outcome.write_seconds)
    except BaseException:
        client.cancel(list(futures))
        raise
