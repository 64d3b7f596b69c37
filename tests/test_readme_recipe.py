"""The README's dataset-then-reconstruction recipe at its stated size, in its stated time, below 10% error
(slow: about 3 minutes on 2 cores; ``pytest -m slow -s tests/test_readme_recipe.py`` prints the figures: on an
AMD EPYC, Zen 4, 2 cores, 2026-11-26: simulate 33 s, reconstruct 144 s, 4.99%, held-out PSNR 19.2 dB;
the same dataset with --option seed=0, 1, 2: 4.98%, 5.00%, 5.01%, so the run-to-run spread is a few hundredths
of a point)."""
from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# The recipe's reconstruction may take this much longer than the README says (a machine with other work).
TIME_SLACK = 1.5


def _recipe():
    """The README's simulate line and its --fast reconstruction, with the time and error its comment states."""
    lines = [line for block in re.findall(r"```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
             for line in block.splitlines()]
    simulate = next(line for line in lines if " simulate " in line)
    reconstruct = next(line for line in lines if " reconstruct " in line and "--fast" in line)
    stated = re.search(r"about (\d+)% error in about ([\d.]+) minutes", reconstruct)
    assert stated, f"the README's --fast line states no error and time: {reconstruct}"
    return simulate.split("  #")[0], reconstruct.split("  #")[0], float(stated[1]) / 100, 60 * float(stated[2])


def _run(line, cwd):
    arguments = shlex.split(line)[1:]
    return subprocess.run([sys.executable, "-m", "mi_nest.cli", *arguments, *(
        ["--no-progress"] if arguments[0] == "reconstruct" else [])], cwd=cwd, check=True, capture_output=True,
        text=True, timeout=3600)


@pytest.mark.slow
def test_the_readme_recipe_reconstructs_below_ten_percent_in_its_stated_time(tmp_path):
    simulate, reconstruct, error, seconds = _recipe()
    start = time.perf_counter()
    _run(simulate, tmp_path)
    simulated = time.perf_counter() - start
    start = time.perf_counter()
    _run(reconstruct, tmp_path)
    elapsed = time.perf_counter() - start
    output = shlex.split(reconstruct)[shlex.split(reconstruct).index("-o") + 1]
    metrics = json.loads((tmp_path / output / "reconstruction.json").read_text())["metrics"]
    print(f"README recipe: simulate {simulated:.0f} s, reconstruct {elapsed:.0f} s, deviatoric error "
          f"{100 * metrics['deviatoric_error']:.2f}%, held-out PSNR {metrics['test_psnr']:.1f} dB")
    assert metrics["deviatoric_error"] < 0.10
    assert metrics["deviatoric_error"] < 1.2 * error, f"{metrics['deviatoric_error']:.3f}, the README says {error}"
    assert elapsed < TIME_SLACK * seconds, f"{elapsed:.0f} s, the README says about {seconds:.0f} s"
