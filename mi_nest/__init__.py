"""mi_nest: 3D photoelastic stress tomography (NeST) inside Mitsuba 3.

Importing the package selects ``llvm_ad_mono`` when no Mitsuba variant is set
(``MI_NEST_VARIANT=cuda_ad_mono`` or ``auto`` for a GPU: ``mi_nest.variants``),
registers the plugins (``stress`` medium, ``photoelastic`` integrator,
``polariscope_light`` emitter, ``polariscope`` sensor) and registers them
again after every variant change.

The API, each with its own ``help()``:

- ``load_scene(name_or_file, **defines)`` and ``render(scene)`` -> ``RenderResult`` (named channels, EXR);
- ``Dataset(directory)``: a multi-axis dataset (``mi-nest simulate`` / ``acquire``; ``simulate`` and
  ``SimulationSettings`` make one from Python);
- ``optimize(scene, dataset, **options)`` -> ``Reconstruction``; ``options`` are ``OptimizeConfig``'s,
  flat (``iterations=300``) or as its groups ``Schedule``, ``Optimiser``, ``ForwardModel``, ``FieldConfig``,
  ``Regulariser`` (``REGULARISED``, the default, or ``NO_REGULARISER``) and ``Reporting``; ``FAST_OPTIONS``
  are ``mi-nest reconstruct --fast``'s;
- ``separate(result_or_field, scene)`` -> ``Separation``: the full stress tensor, the mean stress found by
  equilibrium from a deviatoric field (docs/separation.md).
"""
from __future__ import annotations

import glob
import os

from .version import __version__

# Dr.Jit 1.5 crashes on LLVM 15/16 and refuses 14: point it at LLVM 19 when the
# system has it (Debian's libllvm19) and the user has not chosen a library.
if "DRJIT_LIBLLVM_PATH" not in os.environ:
    _llvm19 = sorted(glob.glob("/usr/lib/*-linux-gnu/libLLVM-19.so"))
    if _llvm19:
        os.environ["DRJIT_LIBLLVM_PATH"] = _llvm19[0]

import mitsuba as mi  # noqa: E402

from . import variants  # noqa: E402

DEFAULT_VARIANT = variants.DEFAULT
supported_variant = variants.supported


def _register_plugins():
    if supported_variant(mi.variant()):
        from . import plugins
        plugins.register()


def _on_variant_change(old_variant, new_variant):
    _register_plugins()


if mi.variant() is None:
    variants.set_from_environment()
_register_plugins()
mi.detail.add_variant_callback(_on_variant_change)

from .render import RenderResult, render  # noqa: E402
from .scene import SceneError, load_scene, scene_path  # noqa: E402
from .dataset import Dataset, DatasetError, SimulationSettings, simulate  # noqa: E402
from .reconstruct import (FAST_OPTIONS, NO_REGULARISER, REGULARISED, DivergenceError, FieldConfig,  # noqa: E402
                          ForwardModel, OptimizeConfig, Optimiser, Reconstruction, Regulariser, Reporting, Schedule,
                          optimize)
from .separation import Separation, separate  # noqa: E402

__all__ = ["render", "load_scene", "scene_path", "RenderResult", "SceneError", "Dataset", "DatasetError",
           "SimulationSettings", "simulate", "optimize", "OptimizeConfig", "Schedule", "Optimiser", "ForwardModel",
           "FieldConfig", "Regulariser", "Reporting", "REGULARISED", "NO_REGULARISER", "FAST_OPTIONS",
           "Reconstruction", "DivergenceError", "separate", "Separation", "DEFAULT_VARIANT", "__version__"]
