"""Every script in benchmarks/ runs as documented, at a tiny size: a smoke run, so that none breaks unseen.

Each case runs ``python benchmarks/NAME.py ARGS`` from the checkout's root, as its docstring or the docs give the
command, with only the sizes shrunk (resolutions, rotations, steps, iterations, repeats, rounds, one case or scene
where a script runs several), and checks that it exits 0 and prints what it measures (its table, its ratio). What
a script writes goes under pytest's ``tmp_path`` (``--data``, ``--results``, ``--csv``, ``--output``), never over
the checkout's results. A script that compares this checkout with another is given the checkout itself as its
``--baseline``: a version against itself is a valid smoke run (and must come out identical where the script says
whether the results agree). The figures say nothing at these sizes.

Cost, measured one case after another on 2 cores (AMD EPYC, AVX-512), Dr.Jit's kernel cache warm, in seconds:
viewer_browser 24.2, time_to_accuracy 23.3, refraction 12.2, deterministic_cost 9.3, render_versions 9.2,
dataset 8.2, accuracy_suite 9.5 (two cases), separation 4.9, viewer 4.5, trust_ranking 4.4, iteration_profile 4.2,
forward_versions 3.0, memory 2.8, reconstruction 2.2, methods 1.2, loss 1.0, fem 0.9, smoothness 0.9,
grid_lookup 0.7, forward 0.7, replay 6.0, spectral 3.5, bands 22, cluster 4, gpu 6, network_lattice 2.5: 166 s for the
module (151 s in a busier run; 157 s with an empty kernel cache, where refraction took 31 s). None is marked
slow: the module fits in the default run.
"""
from __future__ import annotations

import importlib
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "mi_nest.cli"]
TIMEOUT = 300   # seconds per script; the slowest takes a tenth of it
DISK_TARGET = ["disk_compression", "-D", "load=100", "-D", "contact_width=4"]


def _run(arguments: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(arguments, cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT)


def _disk_target(data: Path) -> Path:
    """The accuracy suite's disk target dataset (read noise 0.01, seed 0, 64 x 64), on 2 x 2 rotations."""
    done = _run([*CLI, "simulate", *DISK_TARGET, "-o", str(data), "--azimuth", "2", "--elevation", "2", "--res",
                 "64", "--noise", "0.01", "--seed", "0"])
    assert done.returncode == 0, done.stderr[-3000:]
    return data


def _finished_reconstruction(tmp_path: Path) -> Path:
    """A finished ``mi-nest reconstruct`` of a simulated dataset, as the accuracy suite leaves them, tiny."""
    data = _disk_target(tmp_path / "data")
    result = tmp_path / "suite" / "disk_100N"
    done = _run([*CLI, "reconstruct", str(data), "-o", str(result), "--iterations", "5", "--option", "batch_size=64",
                 "--resolution", "8", "--allow-aliased", "--no-progress"])
    assert done.returncode == 0, done.stderr[-3000:]
    return result


def _reconstruction_and_its_twin(tmp_path: Path) -> None:
    """:func:`_finished_reconstruction` and a copy of it as its seed-1 twin: their error maps rank each other
    perfectly (``rho_twin_error=1.0``)."""
    result = _finished_reconstruction(tmp_path)
    shutil.copytree(result, result.with_name(f"{result.name}_seed1"))


# Per script: its arguments ({tmp}: pytest's tmp_path, {root}: this checkout), the lines its output must have
# (regular expressions, each matched against a whole line) and the files it must write under {tmp}.
CASES = {
    "accuracy_suite": (["--quick", "--cases", "disk_100N,disk_100N_seed1", "--minutes", "0.02", "--data",
                        "{tmp}/suite", "--results", "{tmp}/results"],
                       [r"disk_100N: [\d.]+% in [\d.]+ s \(\d+ iterations, grid .*; target 5%: (yes|no)\)",
                        r"\| case \| data \| options \| time \| iterations \| deviatoric error \|.*",
                        r"\| disk_100N \(the disk target\) \| disk_compression load=100 contact_width=4, 6x6 .*",
                        r"\| disk_100N \| [\d.]+ \| [\d.]+% \(seed 0\), [\d.]+% \(seed 1\) \| [\d.]+ points \| "
                        r"[\d,]+, [\d,]+ \|"],
                       ["results/accuracy_suite_quick.csv", "results/accuracy_suite_quick.png"]),
    "bands": (["--levels", "300", "--seeds", "0", "--minutes", "0.02", "--res", "8", "--data", "{tmp}/data",
               "--results", "{tmp}/results"],
              [r"load 300, one band, seed 0: [\d.]+% \(\d+ iterations in [\d.]+ s; one band aliased in \d+% of the "
               r"pixels\)",
               r"load 300, RGB camera, seed 0: [\d.]+% .*",
               r"\| load 300 \| \d+% \| [\d.]+% \([\d.]+ to [\d.]+\) \| [\d.]+% \([\d.]+ to [\d.]+\) \| [\d.]+% "
               r"\([\d.]+ to [\d.]+\) \| [\d.]+% \([\d.]+ to [\d.]+\) \|"],
              ["results/bands.csv", "results/bands.png"]),
    "cluster": (["--rotations", "2", "--res", "16"],
                [r"Every dataset the same as the one process's, channel for channel \(4 rotations\)\.",
                 r"\| LocalCluster, 2 workers \| [\d.]+ s \| [\d.]+ s \| [\d.]+ s \| [\d.]+ s \| [\d.]+ ms "
                 r"\| [\d.]+x \|",
                 r"Scheduling overhead: [\d.]+ ms per rotation on 1 worker .*"], []),
    "gpu": (["--res", "16", "--spp", "1", "--repeats", "1", "--iterations", "3", "--rotations", "1"],
            [r"CPU: .*; GPU: .*", r"\| llvm_ad_mono \| [\d.e+]+ \| [\d.]+ \| [\d.]+ min \|",
             r"(No CUDA device on this machine: .*|GPU / CPU: forward [\d.]+x, .*)"], []),
    "dataset": (["--baseline", "{root}", "--rotations", "2", "--res", "16"],
                [r"scene +version +total s +render ms +write ms +peak MiB",
                 r"disk +this checkout +[\d.]+ +[\d.]+ +[\d.]+ +\d+",
                 r"kitten +wall time, baseline / this checkout: [\d.]+x"], []),
    "deterministic_cost": (["--iterations", "10", "--data", "{tmp}/disk_target"],
                           [r"2 threads \(default\): [\d.]+ and [\d.]+ iterations/s; errors .*",
                            r"one thread \(deterministic\): .*grids differ by up to 0 stress scales",
                            r"deterministic / default time per iteration: [\d.]+"], []),
    "fem": (["--tets", "2000"],
            [r"tets \d+, nodes \d+, P1 dofs \d+, solver amg \(\d+ iterations, .*",
             r"centre s_x - s_y [\d.]+ MPa vs Frocht [\d.]+ MPa \([-+][\d.]+%\)"], []),
    "forward": (["--res", "16", "--steps", "16", "--repeats", "1"],
                [r"method +best s +median s +rays +steps/ray +ray-steps/s +vs NumPy",
                 r"Dr\.Jit mi_nest .*x",
                 r"ratio Dr\.Jit / NumPy \(best of 1\): [\d.]+x with mi\.render, .*",
                 r"agreement Dr\.Jit vs NumPy: .*"], []),
    "forward_versions": (["--baseline", "{root}", "--rounds", "1", "--", "--res", "16", "--steps", "16", "--repeats",
                          "1"],
                         [r"best: this checkout .*, baseline .* ray-steps/s; this checkout / baseline [\d.]+x",
                          r"per round: [\d.]+x; median [\d.]+x"], []),
    "grid_lookup": (["--res", "16", "--steps", "8", "--nodes", "8", "--repeats", "1"],
                    [r".*the face grid's lookup agrees with the texture's within .*",
                     r" +face grid, 2 channels \(ProjectedGrid\) +[\d.]+ ms +[\d.e+]+ lookups/s"], []),
    "iteration_profile": (["--scene", "disk_compression", "-D", "load=100", "-D", "contact_width=4", "--rotations",
                           "2", "--iterations", "10"],
                          [r" +whole step +[\d.]+ ms/iteration", r" +trace_rays \(primal\) +[\d.]+ ms/iteration",
                           r" +kernels execute [\d.]+ ms of [\d.]+ \(\d+ launches\), .*"], []),
    "loss": ([], [r"before [\d.]+ ms, now [\d.]+ ms, ratio [\d.]+x; loss .*, gradients differ by at most .*"], []),
    "memory": (["--data", "{tmp}/disk", "--iterations", "20", "--every", "5", "--rotations", "2"],
               [r" +iteration +20: +[\d.]+ MiB",
                r"second half: [\d.]+ to [\d.]+ MiB, slope [-+][\d.]+ MiB per 1000 iterations"], []),
    "methods": (["--res", "32"],
                [r"method +seconds +error +step mm +speed-up", r"auto +[\d.]+ +[\d.e+-]+ +[\d.]+ +[\d.]+x",
                 r"magnus4 \d+ steps, product \(midpoint\) \d+ steps: [\d.]+x fewer \(target: at least 4x\)"], []),
    "network_lattice": (["--repeats", "1"],
                        [r"CPU: .*, Dr\.Jit threads: \d+",
                         *(rf"{kind} .*: [\d.]+ ms by cooperative vectors, [\d.]+ ms by matrix products \([\d.]+ "
                           r"times faster\); samples differ by [\d.e+-]+ at most, gradients by [\d.e+-]+ of the "
                           r"largest" for kind in ("mlp", "hashgrid"))], []),
    "reconstruction": (["--baseline", "{root}", "--rotations", "2", "--res", "16", "--iterations", "5",
                        "--resolution", "6", "--batch-size", "64", "--rounds", "1"],
                       [r"round 1 baseline +[\d.]+ it/s .*", r"ratio this checkout / baseline: [\d.]+",
                        r"results: identical \(loss and error, every round\)"], []),
    "replay": (["--scene", "disk_compression", "-D", "load=100", "-D", "contact_width=4", "--rotations", "2",
                "--resolution", "8", "--at", "2", "--repeats", "1"],
               [r".*grid 8x8x3, \d+ rays, \d+ Dr\.Jit threads, best of 1",
                *(rf"  {step}: primal [\d.]+ ms \(keeping its segments [\d.]+\); replay querying the scene [\d.]+ ms, "
                  r"through the kept segments [\d.]+ ms: [\d.]+x; gradients apart by [\d.e+-]+ of their largest"
                  for step in ("the grid's step", "one step a segment"))], []),
    "refraction": (["--rounds", "1", "--res", "16", "--spp", "1", "--step", "1", "--iterations", "5", "--rotations",
                    "2"],
                   [r"disk_compression: render 16x16, 1 spp, step 1\.0 mm, median of 1",
                    r" +with ghosts \(\d+\) +[\d.]+ s .*x the straight render",
                    r"kitten: reconstruction, 5 iterations of 2048 rays",
                    r" +with ghosts \(\d+\) +[\d.]+ it/s +[\d.]+x the straight rate"], []),
    "render_versions": (["--baseline", "{root}"],
                        [r" +grid perspective +largest difference .*", r"every scene within 0\.0001 of the baseline"],
                        []),
    "separation": (["--quick", "--csv", "{tmp}/separation_quick.csv"],
                   [r"\{'case': 'Frocht disk, 4 mm contacts', 'source': 'exact deviator', .*",
                    r"\{'case': '32\^3 lattice \(a cube\)', 'source': 'speed', .*",
                    r".*; wrote .*separation_quick\.csv"],
                   ["separation_quick.csv"]),
    "smoothness": (["--repeats", "2"],
                   [r"edge None: automatic [\d.]+ ms, custom op [\d.]+ ms, ratio [\d.]+x",
                    r"edge 0\.5: automatic [\d.]+ ms, custom op [\d.]+ ms, ratio [\d.]+x"], []),
    "spectral": (["--res", "16", "--lanes", "1", "3", "--repeats", "1", "--grid-nodes", "8"],
                 [r"field +path +waves +one march s .*",
                  r"grid +rays +3 +[\d.]+ +[\d.]+ +[\d.e+]+ +[\d.]+ +[\d.]+x +[\d.e+-]+",
                  r"white light, disk_compression at 300 N, n = 1, 16x16, 41 wavelengths: [\d.]+ s in spectral "
                  r"marches, [\d.]+ s one render per wavelength \([\d.]+x\); sRGB differs by .*",
                  r"white light, disk_compression at 300 N, n = 1.55, 16x16, 41 wavelengths: [\d.]+ s in spectral "
                  r"marches, [\d.]+ s one render per wavelength \([\d.]+x\); sRGB differs by .*",
                  r"analytic: 3 wavelengths in one march cost [\d.]+ \(render\) and [\d.]+ \(ray batch\) times one "
                  r"wavelength's \(target: well under 3\)"], []),
    "time_to_accuracy": (["--baseline", "{root}", "--output", "{tmp}/tta", "--flags=--fast", "--rotations", "2",
                          "--iterations", "5"],
                         [r"disk +baseline +5 it +[\d.]+ s +error .*",
                          r"disk: baseline / this checkout optimisation time [\d.]+x",
                          r"kitten: baseline / this checkout optimisation time [\d.]+x"],
                         ["tta/time_to_accuracy.csv", "tta/time_to_accuracy.png"]),
    "trust_ranking": (["{tmp}/suite/disk_100N", "--csv", "{tmp}/trust_ranking.csv"],
                      [r"case=disk_100N nodes=\d+ trust_s=[\d.]+ .* rho_imbalance=[-\d.]+ .* rho_twin_error=1\.0 .*",
                       r"wrote .*"],
                      ["trust_ranking.csv", "suite/disk_100N/trust.npz"]),
    "viewer": (["--frames", "2"],
               [r"scene +frames +256x256 fps +128x128 fps", r"disk_compression +dragging +[\d.]+ +[\d.]+",
                r"kitten +slice +[\d.]+ +[\d.]+"], []),
    "viewer_browser": (["--baseline", "{root}", "--scene", "disk_compression", "--res", "64", "--moving-res", "32",
                        "--steps", "2", "--drag-seconds", "0.5"],
                       [r"disk_compression: this checkout +\| +baseline",
                        r" +slider step to frame, median \(ms\) +[\d.]+ +\| +[\d.]+",
                        r" +drag frames per second +[\d.]+ +\| +[\d.]+"], []),
}
# What a script reads that a user makes first (the accuracy suite's datasets and results), made tiny in {tmp}.
PREPARE = {"deterministic_cost": lambda tmp: _disk_target(tmp / "disk_target"),
           "trust_ranking": _reconstruction_and_its_twin}


def test_every_script_has_a_case():
    assert sorted(CASES) == sorted(path.stem for path in (ROOT / "benchmarks").glob("*.py"))


@pytest.mark.parametrize("name", sorted(CASES))
def test_benchmark_runs(name, tmp_path):
    if name == "viewer_browser":
        from test_viewer import _browser_or_skip
        _browser_or_skip()
    arguments, expected, written = CASES[name]
    if name in PREPARE:
        PREPARE[name](tmp_path)
    done = _run([sys.executable, f"benchmarks/{name}.py",
                 *(a.format(tmp=tmp_path, root=ROOT) for a in arguments)])
    assert done.returncode == 0, f"benchmarks/{name}.py failed:\n{done.stdout[-3000:]}{done.stderr[-3000:]}"
    lines = done.stdout.splitlines()
    for pattern in expected:
        assert any(re.fullmatch(pattern, line) for line in lines), \
            f"benchmarks/{name}.py printed no line like {pattern!r}:\n{done.stdout[-3000:]}"
    for path in written:
        assert (tmp_path / path).is_file(), f"benchmarks/{name}.py did not write {path}"


def _accuracy_suite():
    sys.path.insert(0, str(ROOT / "benchmarks"))      # the script and its own imports (reconstruction.cpu_name)
    try:
        return importlib.import_module("accuracy_suite")
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


def test_the_suite_keeps_its_rows_when_a_run_adds_a_column(tmp_path):
    """A CSV written before a column existed takes a new run's row with it: nothing the earlier runs measured is
    lost, and their empty cell reads as the neighbour loss off (the defaults before it)."""
    suite = _accuracy_suite()
    path = tmp_path / "suite.csv"
    suite.write_rows([{"case": "disk_100N", "flags": "", "deviatoric_error": "0.046", "iterations": "55755"}], path)
    rows = suite.read_rows(path) + [{"case": "disk_100N_seed1", "flags": "--option seed=1", "deviatoric_error": 0.047,
                                     "iterations": 37657, "neighbour_loss": 1.0}]
    suite.write_rows(rows, path)
    again = suite.read_rows(path)
    assert [row["case"] for row in again] == ["disk_100N", "disk_100N_seed1"]
    assert [suite.neighbour_weight(row) for row in again] == [0.0, 1.0]


def test_the_suite_spread_compares_seeds_of_one_configuration():
    suite = _accuracy_suite()
    rows = [{"case": "disk_100N", "flags": "", "deviatoric_error": "0.046", "iterations": "55755",
             "neighbour_loss": "0.0"},
            {"case": "disk_100N_seed1", "flags": "--option seed=1", "deviatoric_error": "0.046",
             "iterations": "52582", "neighbour_loss": "0.0"},
            {"case": "disk_100N_neighbours_seed1", "flags": "--option neighbour_loss=1 --option seed=1",
             "deviatoric_error": "0.047", "iterations": "37657", "neighbour_loss": "1.0"}]
    table = suite.spread(rows)
    assert "| disk_100N | 0 | 4.6% (seed 0), 4.6% (seed 1) | 0.00 points | 55,755, 52,582 |" in table
    assert "| disk_100N | 1 |" not in table         # one seed under the loss: no spread yet
    rows.append({"case": "disk_100N_neighbours", "flags": "--option neighbour_loss=1", "deviatoric_error": "0.046",
                 "iterations": "40821", "neighbour_loss": "1.0"})
    assert "| disk_100N | 1 | 4.6% (seed 0), 4.7% (seed 1) | 0.10 points | 40,821, 37,657 |" in suite.spread(rows)
