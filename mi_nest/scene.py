"""Scenes: loading one (a file or a shipped name, ``$NAME`` defines) and finding the polariscope's parts in it.

Specimens, the light, the camera and the integrator are found by their plugin
types. The plugin modules are re-imported whenever the Mitsuba variant changes
(``plugins/__init__.py``), so each class is looked up on its module at call
time, never kept from an earlier import.
"""
from __future__ import annotations

import argparse
import os
import stat
import xml.etree.ElementTree as ElementTree
from contextlib import contextmanager
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

import mitsuba as mi
import numpy as np

from . import variants

if TYPE_CHECKING:
    from .plugins.photoelastic import PhotoelasticIntegrator
    from .plugins.polariscope import PolariscopeCamera
    from .plugins.polariscope_light import PolariscopeLight
    from .plugins.stress import StressMedium
    from .tracer import Tracer


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


def scene_file(path: str | Path) -> Path:
    """The scene XML a path or shipped scene name stands for: a file this process may read."""
    path = Path(path)
    # A bare name is a shipped scene unless something other than a folder has that name here (a folder named
    # like it, such as the output directory of `mi-nest simulate kitten -o kitten`, is not a scene).
    if len(path.parts) == 1 and (path.is_dir() or not path.exists()):
        path = scene_path(path.name)
    if not path.exists():
        raise SceneError(f"scene file not found: {path}")
    if not path.is_file():
        raise SceneError(f"{path} is {_special_file_kind(path)}, not a scene file; give a scene XML file")
    if not os.access(path, os.R_OK):
        raise SceneError(f"{path}: permission denied: this user may not read the scene file; check its permissions")
    return path.resolve()


# What a path that is not a regular file is, by the test of its mode.
_SPECIAL_FILES = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a named pipe (FIFO)"), (stat.S_ISSOCK, "a socket"),
                  (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"))


def _special_file_kind(path):
    mode = path.stat().st_mode
    return next((kind for test, kind in _SPECIAL_FILES if test(mode)), "not a regular file")


def parse_define(text: str) -> tuple[str, str]:
    """``(NAME, VALUE)`` of a command line's ``-D NAME=VALUE``: the type of its ``argparse`` option."""
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got '{text}'")
    return name, value


def load_scene(path: str | Path, **defaults) -> mi.Scene:
    """Load a scene XML (a path, or the name of a shipped scene) filling ``$name`` defaults.

    Embree's robust intersections are switched on whatever the file says (a
    flag in an included file is lost, too): without them a ray through a mesh
    edge can miss both triangles, which the walk only mends by querying again.
    The scene's id is its file, so that messages can name it.
    """
    variants.require_usable()
    path = scene_file(path)
    try:
        scene = _load_robust(path, {k: str(v) for k, v in defaults.items()})
    except Exception as error:
        raise SceneError(f"{path}: {_without_traceback(str(error))}") from error
    if not scene.id():
        scene.set_id(str(path))
    # Scenes take no attributes and no weak references: keyed by identity, checked against the id on lookup.
    _ORIGINS[id(scene)] = (scene.id(), path, {k: str(v) for k, v in defaults.items()})
    return scene


# What load_scene loaded each scene from: id(scene) -> (its id, the file, the defines).
_ORIGINS: dict[int, tuple[str, Path, dict]] = {}


def scene_origin(scene: mi.Scene) -> tuple[Path, dict] | None:
    """The file and the defines that :func:`load_scene` loaded ``scene`` from (None for a scene made otherwise):
    what a result records so that its views can load the same scene again."""
    origin = _ORIGINS.get(id(scene))
    if origin is None or origin[0] != scene.id():
        return None
    return origin[1], dict(origin[2])


# The plugins' properties that may name a file: meshes and stress files, a light's spectrum, a camera's curves.
NAMED_FILES = ("filename", "spectrum", "bands")


def scene_inputs(path: str | Path, **defaults) -> list[Path]:
    """The files that loading the scene ``path`` with ``defaults`` reads: the scene file, the files it includes
    and those its plugins name (meshes, stress files, spectra and camera curves), resolved as loading resolves
    them. What an output must not overwrite, and what a dataset's record of its scene's content covers."""
    path = scene_file(path)
    config = mi.parser.ParserConfig(mi.variant())
    with _resolving_beside(path) as resolver:
        try:
            state = mi.parser.parse_file(config, str(path), **{k: str(v) for k, v in defaults.items()})
        except Exception as error:
            raise SceneError(f"{path}: {_without_traceback(str(error))}") from error
        named = [resolver.resolve(str(node.props[key])) for node in state.nodes for key in NAMED_FILES
                 if key in node.props and (key == "filename" or str(node.props[key]).lower().endswith(".csv"))]
    files = [Path(str(name)) for name in [*state.files, *named]]
    return list(dict.fromkeys(file.resolve() for file in files if file.is_file()))


def scene_defaults(path: Path) -> dict[str, str]:
    """The ``<default name=... value=...>`` entries of a scene file."""
    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError):
        return {}
    return {element.get("name"): element.get("value") for element in root.iter("default")
            if element.get("name") is not None}


@contextmanager
def _resolving_beside(path):
    """Relative file names resolve beside the scene ``path`` inside, as ``mi.load_file`` resolves them."""
    previous = mi.file_resolver()
    resolver = mi.FileResolver(previous)
    resolver.prepend(str(path.parent))
    mi.set_file_resolver(resolver)
    try:
        yield resolver
    finally:
        mi.set_file_resolver(previous)


def _load_robust(path, defaults):
    """``mi.load_file`` with the scene's ``embree_use_robust_intersections`` set."""
    config = mi.parser.ParserConfig(mi.variant())
    # Serial loading: Mitsuba's parallel loader runs plugin constructors on worker threads
    # with small stacks, which has crashed NumPy/SciPy code in them; scenes here are small.
    config.parallel = False
    with _resolving_beside(path):
        state = mi.parser.parse_file(config, str(path), **defaults)
        if state.root.type == mi.ObjectType.Scene:
            state.root.props["embree_use_robust_intersections"] = True
        mi.parser.transform_all(config, state)
        return mi.parser.instantiate(config, state)


def _without_traceback(message):
    """Mitsuba embeds a plugin's Python traceback in its error; keep location and cause."""
    lines = [line.replace("Traceback (most recent call last):", "") for line in message.splitlines()
             if not line.startswith("  File ")]
    return " ".join(" ".join(line.split()) for line in lines if line.strip())


def photoelastic_integrator(scene: mi.Scene) -> PhotoelasticIntegrator:
    """The scene's ``photoelastic`` integrator; any other is refused."""
    from .plugins import photoelastic
    integrator = scene.integrator()
    if not isinstance(integrator, photoelastic.PhotoelasticIntegrator):
        raise SceneError(f'the scene\'s integrator is {integrator.class_name()}; mi_nest renders with '
                         '<integrator type="photoelastic">')
    return integrator


def scene_tracer(scene: mi.Scene) -> Tracer:
    """The tracer of the scene's ``photoelastic`` integrator (its properties as a :class:`TracerConfig`)."""
    return photoelastic_integrator(scene).tracer


def scene_sensor(scene: mi.Scene) -> mi.Sensor:
    """The scene's first sensor, the one mi_nest renders with; a scene without one is refused."""
    sensors = scene.sensors()
    if not sensors:
        raise SceneError(f'{scene.id() or "the scene"} has no sensor: add a <sensor type="polariscope"> (the camera '
                         "and the polariscope's analysing side) to it")
    return sensors[0]


def polariscope_camera(scene: mi.Scene) -> PolariscopeCamera:
    """The scene's ``polariscope`` sensor (its first); any other is refused."""
    from .plugins import polariscope
    sensor = scene_sensor(scene)
    if not isinstance(sensor, polariscope.PolariscopeCamera):
        raise SceneError(f'the scene needs <sensor type="polariscope">, it has {sensor.class_name()}')
    return sensor


def camera_of(scene: mi.Scene) -> mi.Sensor:
    """The Mitsuba camera (orthographic or perspective) inside the scene's polariscope sensor: what poses move."""
    return polariscope_camera(scene).camera


def polariscope_light(scene: mi.Scene) -> PolariscopeLight:
    """The scene's one ``polariscope_light`` emitter."""
    from .plugins import polariscope_light as light_plugin
    lights = [e for e in scene.emitters() if isinstance(e, light_plugin.PolariscopeLight)]
    if len(lights) != 1:
        raise SceneError(f'the scene needs exactly one <emitter type="polariscope_light">, found {len(lights)}')
    return lights[0]


def is_specimen(shape: mi.Shape) -> bool:
    """Whether ``shape`` holds a ``stress`` medium inside."""
    from .plugins import stress
    return isinstance(shape.interior_medium(), stress.StressMedium)


def specimen_file(shape: mi.Shape) -> str | None:
    """The stress file a ``specimen`` shape was made from (None for other shapes)."""
    from .plugins import specimen
    return shape.filename if isinstance(shape, specimen.Specimen) else None


def specimen_shapes(scene: mi.Scene) -> list[mi.Shape]:
    """The scene's specimens (shapes with a ``stress`` medium inside); a scene without one is refused."""
    shapes = [s for s in scene.shapes() if is_specimen(s)]
    if not shapes:
        raise SceneError("the scene has no specimen (no shape with a stress medium inside)")
    return shapes


def specimen_bounds(shapes: list[mi.Shape]) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)``: the bounding box of the specimen ``shapes``, as NumPy arrays (mm)."""
    return (np.min([np.array(s.bbox().min) for s in shapes], axis=0),
            np.max([np.array(s.bbox().max) for s in shapes], axis=0))


def specimen_media(scene: mi.Scene) -> list[StressMedium]:
    """The distinct stress media of the scene's specimens."""
    return list({id(s.interior_medium()): s.interior_medium() for s in specimen_shapes(scene)}.values())


def scene_field(scene: mi.Scene):
    """The one stress field of ``scene``'s specimens, or None when they hold different fields."""
    media = specimen_media(scene)
    return media[0].field if len({id(m.field) for m in media}) == 1 else None


def pose(scene: mi.Scene, to_world: np.ndarray) -> None:
    """Move the scene's polariscope camera to ``to_world`` (4x4)."""
    params = mi.traverse(camera_of(scene))
    params["to_world"] = mi.Transform4f(np.asarray(to_world, dtype=np.float32))
    params.update()


def reference_pose(scene: mi.Scene) -> np.ndarray:
    """The 4x4 ``to_world`` of the scene's polariscope camera where it stands."""
    return np.array(mi.traverse(camera_of(scene))["to_world"].matrix, dtype=np.float64).reshape(4, 4)
