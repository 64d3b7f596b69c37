"""The Mitsuba variant mi_nest runs on (issue 38): LLVM's by default, CUDA's when asked for and present; a variant
that cannot run here refused in one line, never swapped silently for another."""
import os
import subprocess
import sys

import drjit as dr
import mitsuba as mi
import pytest

from mi_nest import variants

CUDA = bool(dr.has_backend(dr.JitBackend.CUDA))


def _run(code, **environment):
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, **environment})


def test_the_variant_is_chosen_by_name_or_automatically():
    assert variants.choose(None) == variants.choose("") == "llvm_ad_mono"
    assert variants.choose("llvm_ad_mono") == "llvm_ad_mono"
    assert variants.choose("auto") == ("cuda_ad_mono" if CUDA else "llvm_ad_mono")
    for bad in ("scalar_rgb", "llvm_ad_rgb", "bogus"):
        with pytest.raises(ValueError, match=f"mi_nest runs on the variants llvm_ad_mono, cuda_ad_mono or auto, "
                                             f"not '{bad}'"):
            variants.choose(bad)


@pytest.mark.skipif(CUDA, reason="this machine has a CUDA device")
def test_a_gpu_variant_without_a_gpu_is_refused_not_replaced(tmp_path):
    with pytest.raises(ValueError, match="cuda_ad_mono needs a CUDA device and its driver, and this machine has "
                                         "none: use llvm_ad_mono"):
        variants.choose("cuda_ad_mono")
    # From the environment: the import goes on, the work is refused (the API and the command line alike).
    done = _run("import mi_nest, mitsuba as mi\nprint(mi.variant())\ntry:\n    mi_nest.load_scene('disk_compression')"
                "\nexcept ValueError as error:\n    print(error)", MI_NEST_VARIANT="cuda_ad_mono")
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["llvm_ad_mono", "MI_NEST_VARIANT=cuda_ad_mono: cuda_ad_mono needs a CUDA "
                                        "device and its driver, and this machine has none: use llvm_ad_mono (or auto, "
                                        "which takes the GPU where there is one)"]
    for command, environment in ((["--variant", "cuda_ad_mono"], {}), ([], {"MI_NEST_VARIANT": "bogus"})):
        done = subprocess.run([sys.executable, "-m", "mi_nest.cli", *command, "render", "disk_compression", "-o",
                               str(tmp_path / "x.exr")], capture_output=True, text=True, timeout=300,
                              env={**os.environ, **environment})
        assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
        assert done.stderr.startswith("mi-nest: error: ") and not (tmp_path / "x.exr").exists()


def test_auto_and_the_command_line_choose_the_variant_for_the_processes_a_run_starts(tmp_path):
    done = _run("import mi_nest, mitsuba as mi, os\nprint(mi.variant())", MI_NEST_VARIANT="auto")
    assert done.stdout.strip() == ("cuda_ad_mono" if CUDA else "llvm_ad_mono"), done.stderr
    done = _run("from mi_nest.cli import main\nimport os, mitsuba as mi\n"
                f"main(['--variant', 'llvm_ad_mono', 'render', 'disk_compression', '-o', r'{tmp_path / 'x.exr'}', "
                "'-D', 'res=8'])\nprint(mi.variant(), os.environ['MI_NEST_VARIANT'])")
    assert done.stdout.splitlines()[-1] == "llvm_ad_mono llvm_ad_mono", done.stderr
    assert (tmp_path / "x.exr").is_file()


def test_a_worker_takes_the_run_s_variant_or_refuses_it(tmp_path):
    from dataclasses import replace

    from mi_nest.dataset import SimulationSettings
    from mi_nest.dataset.rotation_files import RotationJob
    from mi_nest.dataset.sharded import render_on_worker
    job = RotationJob("disk_compression", {}, tmp_path, SimulationSettings(azimuths=1, elevations=1, res=8),
                      {"channels": []}, "llvm_ad_mono")
    if not CUDA:
        with pytest.raises(ValueError, match="cuda_ad_mono needs a CUDA device"):
            render_on_worker(replace(job, variant="cuda_ad_mono"), {"index": 0, "file": "rotations/r.exr"}, None)
    assert mi.variant() == "llvm_ad_mono"
