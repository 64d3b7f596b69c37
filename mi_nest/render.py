"""Render a photoelastic scene to named channels, in passes with a progress bar."""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import mitsuba as mi

from . import __version__


class SceneError(ValueError):
    """A scene file cannot be found, parsed or rendered."""


def scene_path(name: str) -> Path:
    """Path of a shipped scene, by name (``"disk_compression"``) or file name."""
    file_name = name if name.endswith(".xml") else f"{name}.xml"
    path = Path(resources.files("mi_nest.scenes") / file_name)
    if not path.is_file():
        shipped = sorted(p.stem for p in Path(resources.files("mi_nest.scenes")).glob("*.xml"))
        raise SceneError(f"no shipped scene '{name}'; available: {shipped}")
    return path


def scene_file(path) -> Path:
    """The scene XML a path or shipped scene name stands for."""
    path = Path(path)
    if not path.exists() and len(path.parts) == 1:
        path = scene_path(path.name)
    if not path.is_file():
        raise SceneError(f"scene file not found: {path}")
    return path.resolve()


def load_scene(path, **defaults):
    """Load a scene XML (a path, or the name of a shipped scene) filling ``$name`` defaults."""
    path = scene_file(path)
    try:
        # Serial loading: Mitsuba's parallel loader runs plugin constructors on worker threads
        # with small stacks, which has crashed NumPy/SciPy code in them; scenes here are small.
        return mi.load_file(str(path), parallel=False, **{k: str(v) for k, v in defaults.items()})
    except Exception as error:
        raise SceneError(f"{path}: {_without_traceback(str(error))}") from error


def _without_traceback(message):
    """Mitsuba embeds a plugin's Python traceback in its error; keep location and cause."""
    lines = [line for line in message.splitlines()
             if not line.startswith(("Traceback (most recent call last)", "  File "))]
    return " ".join(line.strip() for line in lines if line.strip())


@dataclass
class RenderResult:
    """Named ``(H, W)`` float32 channels; ``Y`` is the scene's own polariscope."""
    channels: dict
    seconds: float
    metadata: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)  # what the integrator warned about, once each

    @property
    def main(self):
        return self.channels["Y"]

    def write_exr(self, path):
        from .io.exr import write_channels
        write_channels(path, self.channels, metadata=self.metadata)

    def write_png(self, path, channel="Y"):
        from .io.preview import write_preview
        write_preview(path, self.channels[channel])


def render(scene, spp=None, seed=0, passes=None, progress=False) -> RenderResult:
    """Render ``scene`` (a loaded scene) and return its named channels.

    The samples are split into ``passes`` kernel launches of equal size (default:
    up to 16) so that ``progress=True`` can show a bar; every pass uses its own seed
    and the passes are averaged, which is exact for box-filtered films.
    """
    sensor = scene.sensors()[0]
    film = sensor.film()
    integrator = scene.integrator()
    if not hasattr(integrator, "check_scene"):
        raise SceneError(f'the scene\'s integrator is {integrator.class_name()}; mi_nest renders with '
                         '<integrator type="photoelastic">')
    spp = spp or sensor.sampler().sample_count()
    if spp < 1:
        raise SceneError(f"spp must be >= 1, got {spp}")
    if passes is None:
        passes = max(p for p in range(1, min(spp, 16) + 1) if spp % p == 0)
    if spp % passes:
        raise SceneError(f"spp={spp} cannot be split into {passes} equal passes")
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=passes, desc="render", unit="pass", leave=False)
    start = time.perf_counter()
    total = None
    # Every pass checks the same things (aliasing, rk4 norm): report each kind once, the last pass's.
    with warnings.catch_warnings(record=True) as caught, integrator.deciding_once(scene, sensor):
        warnings.simplefilter("always")
        for index in range(passes):
            try:
                image = mi.render(scene, spp=spp // passes, seed=seed * passes + index).numpy()
            except Exception:
                # mi.render reports only "error while performing a custom differentiable
                # operation"; checking the scene raises the cause when the scene is at fault.
                integrator.check_scene(scene, sensor)
                raise
            total = image if total is None else total + image
            if bar is not None:
                bar.update()
    if bar is not None:
        bar.close()
    last_of_kind = {(w.category, w.filename, w.lineno): w for w in caught}
    for w in last_of_kind.values():
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    seconds = time.perf_counter() - start
    if passes > 1:
        total /= passes
    names = integrator.channel_names(film)
    if len(names) != total.shape[-1]:
        raise SceneError(f"film produced {total.shape[-1]} channels but names {names}")
    # Views into the (H, W, C) image: a transposing copy costs more than the render.
    channels = {name: total[..., index] for index, name in enumerate(names)}
    metadata = {"mi_nest.version": __version__, "mi_nest.spp": spp,
                "mi_nest.integrator": integrator.class_name()}
    return RenderResult(channels=channels, seconds=seconds, metadata=metadata,
                        warnings=[str(w.message) for w in last_of_kind.values()])
