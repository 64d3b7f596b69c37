"""Package wiring: default variant, plugin registration, re-registration on variant change."""
import os
import subprocess
import sys

import numpy as np

import mi_nest


def run_python(code):
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                            env={**os.environ})
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_import_selects_llvm_ad_mono_and_registers_plugins():
    out = run_python(
        "import mi_nest, mitsuba as mi\n"
        "print(mi.variant())\n"
        "s = mi_nest.load_scene('disk_compression', res=8, spp=1)\n"
        "print(type(s.integrator()).__name__, type(s.shapes()[0].interior_medium()).__name__)\n")
    assert out.split() == ["llvm_ad_mono", "PhotoelasticIntegrator", "StressMedium"]


def test_plugins_are_registered_again_after_a_variant_change():
    out = run_python(
        "import mi_nest, mitsuba as mi\n"
        "mi.set_variant('llvm_ad_rgb')\n"
        "mi.set_variant('llvm_ad_mono')\n"
        "r = mi_nest.render(mi_nest.load_scene('disk_compression', res=8, spp=1))\n"
        "print(r.main.shape, isinstance(mi_nest.load_scene('disk_compression', res=8).integrator(),"
        " mi.ad.integrators.common.ADIntegrator))\n")
    assert out.strip() == "(8, 8) True"


def test_an_explicit_variant_is_respected():
    out = run_python("import mitsuba as mi\nmi.set_variant('llvm_ad_rgb')\nimport mi_nest\nprint(mi.variant())\n")
    assert out.strip() == "llvm_ad_rgb"


def test_shipped_scenes_are_package_data():
    path = mi_nest.scene_path("disk_compression")
    assert path.is_file() and (path.parent / "meshes" / "disk.ply").is_file()


def test_the_stress_medium_documents_every_model():
    from mi_nest.fields import MODELS
    from mi_nest.plugins.stress import StressMedium
    for name in MODELS:
        assert f"``{name}``" in StressMedium.__doc__, name


def test_the_api_explains_itself():
    import pydoc
    for name in ("OptimizeConfig", "Schedule", "Optimiser", "ForwardModel", "FieldConfig", "Regulariser",
                 "Reporting", "SimulationSettings", "simulate", "REGULARISED", "FAST_OPTIONS"):
        assert name in mi_nest.__all__ and getattr(mi_nest, name) is not None
    # help(mi_nest.optimize) names OptimizeConfig, which help(mi_nest) lists.
    assert "OptimizeConfig" in mi_nest.optimize.__doc__
    assert "class OptimizeConfig" in pydoc.render_doc(mi_nest, renderer=pydoc.plaintext)
    for cls, methods in ((mi_nest.Dataset, ("view", "split", "measurements", "ray_batch", "to_world",
                                            "polariscopes", "check_measurements")),
                         (mi_nest.Reconstruction, ("load", "save", "describe", "render"))):
        assert cls.__doc__ and len(cls.__doc__) > 200
        for method in methods:
            assert getattr(cls, method).__doc__, f"{cls.__name__}.{method} has no docstring"


def test_a_reconstruction_s_repr_is_one_short_line():
    from mi_nest.reconstruct import FieldConfig, OptimizeConfig, make_field
    field = make_field(FieldConfig(kind="grid", resolution=4), np.zeros(3), np.ones(3), 1.0)
    history = [{"iteration": i, "loss": 0.1} for i in range(10000)]
    result = mi_nest.Reconstruction(field, OptimizeConfig(), history, {"deviatoric_error": 0.123456,
                                                                       "test_psnr": 30.0}, 12.0)
    text = repr(result)
    assert "\n" not in text and len(text) < 150 and "10000 iterations" in text and "0.1235" in text
