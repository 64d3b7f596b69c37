"""On a GPU (issue 38): the same commands on Mitsuba's CUDA variant give what the LLVM variant gives. Marked
``gpu`` and skipped on machines without a CUDA device; run with ``pytest -m gpu tests/test_gpu.py`` where one is."""
import json
import subprocess
import sys

import drjit as dr
import numpy as np
import pytest

from mi_nest.io.exr import read_channels

pytestmark = [pytest.mark.gpu,
              pytest.mark.skipif(not dr.has_backend(dr.JitBackend.CUDA), reason="no CUDA device on this machine")]


def _mi_nest(*arguments, variant):
    done = subprocess.run([sys.executable, "-m", "mi_nest.cli", "--variant", variant, *arguments],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_a_render_on_the_gpu_equals_the_cpu_s(tmp_path):
    for variant in ("llvm_ad_mono", "cuda_ad_mono"):
        _mi_nest("render", "disk_compression", "-o", str(tmp_path / f"{variant}.exr"), "-D", "res=64", "-D",
                 "load=300", variant=variant)
    cpu, gpu = (read_channels(tmp_path / f"{v}.exr") for v in ("llvm_ad_mono", "cuda_ad_mono"))
    assert cpu.keys() == gpu.keys()
    for name in cpu:
        np.testing.assert_allclose(gpu[name], cpu[name], atol=2e-4, err_msg=name)


def test_a_dataset_and_a_reconstruction_run_on_the_gpu(tmp_path):
    _mi_nest("simulate", "disk_compression", "-o", str(tmp_path / "data"), "--azimuth", "4", "--elevation", "4",
             "--res", "32", "-D", "load=60", "-D", "contact_width=4", variant="cuda_ad_mono")
    _mi_nest("reconstruct", str(tmp_path / "data"), "-o", str(tmp_path / "result"), "--iterations", "300",
             "--no-progress", "--allow-aliased", variant="cuda_ad_mono")
    record = json.loads((tmp_path / "result" / "reconstruction.json").read_text())
    losses = [h["loss"] for h in record["history"]]
    assert np.mean(losses[-30:]) < 0.8 * np.mean(losses[:30])
    assert record["metrics"]["deviatoric_error"] < 1.0
