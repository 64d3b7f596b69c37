"""Package wiring: default variant, plugin registration, re-registration on variant change."""
import os
import subprocess
import sys

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
