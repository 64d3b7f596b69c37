"""``mi-nest sweep`` (issue 38): cases as tasks on a LocalCluster; finished ones kept, failed ones reported without
stopping the others; bad sweep files refused before any case starts."""
import csv
import math

import pytest

from mi_nest.cli import _argument_problem, main
from mi_nest.sweep import SweepError, read_sweep

TINY = """
scene = "disk_compression"

[scene_parameters]
contact_width = 4

[simulate]
azimuth = 2
elevation = 2
res = 8
noise = 0.01

[reconstruct]
iterations = 3
resolution = 6
allow_aliased = true
option = { batch_size = 64 }

[vary]
{vary}
"""


def _sweep_file(tmp_path, vary, name="sweep.toml"):
    path = tmp_path / name
    path.write_text(TINY.replace("{vary}", vary))
    return path


def _rows(output):
    with open(output / "sweep.csv") as stream:
        return list(csv.DictReader(stream))


def test_a_sweep_of_four_cases_completes_and_a_rerun_skips_them(tmp_path, capsys):
    path = _sweep_file(tmp_path, '"scene.load" = [20, 40]\n"reconstruct.option.seed" = [0, 1]')
    assert main(["sweep", str(path), "-o", str(tmp_path / "out"), "--workers", "2", "--no-progress"]) == 0
    said = capsys.readouterr().out
    assert "sweep: 4 case(s), 0 finished before, 4 to run" in said and "cluster: 2 worker(s)" in said
    rows = _rows(tmp_path / "out")
    assert [(r["scene.load"], r["reconstruct.option.seed"], r["status"]) for r in rows] == [
        ("20", "0", "done"), ("20", "1", "done"), ("40", "0", "done"), ("40", "1", "done")]
    assert all(0 < float(r["deviatoric_error"]) < math.inf and int(r["iterations"]) == 3 for r in rows)
    # Each case is the commands a user would run: its dataset holds the case's load, its log both commands.
    case = tmp_path / "out" / "cases" / "load=40_seed=1"
    assert '"load": "40"' in (case / "data" / "dataset.json").read_text()
    assert (case / "log.txt").read_text().count("$ mi-nest ") == 2
    assert (tmp_path / "out" / "sweep.png").stat().st_size > 0
    # A rerun starts no cluster and runs nothing.
    finished = {p: p.stat().st_mtime_ns for p in (tmp_path / "out" / "cases").glob("*/row.json")}
    assert main(["sweep", str(path), "-o", str(tmp_path / "out"), "--workers", "2", "--no-progress"]) == 0
    said = capsys.readouterr().out
    assert "4 finished before, 0 to run" in said and "cluster:" not in said
    assert {p: p.stat().st_mtime_ns for p in finished} == finished
    # An edited sweep file does not pass its old results off as its own.
    path.write_text(path.read_text().replace("noise = 0.01", "noise = 0.02"))
    assert main(["sweep", str(path), "-o", str(tmp_path / "out"), "--no-progress"]) == 2
    assert "load=20_seed=0 was run with other settings than" in capsys.readouterr().err


def test_a_failed_case_is_reported_and_the_others_finish(tmp_path, capsys):
    # 0 iterations passes the command line's parser but not the reconstruction: the case fails as it runs.
    path = _sweep_file(tmp_path, '"reconstruct.iterations" = [3, 0]')
    assert main(["sweep", str(path), "-o", str(tmp_path / "out"), "--no-progress"]) == 2
    captured = capsys.readouterr()
    assert "1 of 2 case(s) failed, the first iterations=0: " in captured.err and "'iterations'" in captured.err
    rows = {r["case"]: r for r in _rows(tmp_path / "out")}
    assert rows["iterations=3"]["status"] == "done" and rows["iterations=0"]["status"].startswith("failed: ")
    # The next run retries the failed case only.
    assert main(["sweep", str(path), "-o", str(tmp_path / "out"), "--no-progress"]) == 2
    assert "1 finished before, 1 to run" in capsys.readouterr().out


@pytest.mark.parametrize("vary, refusal", [
    ('"scene.bogus" = [1]', r"case bogus=1: the scene has no parameter 'bogus'; its parameters are .*load"),
    ('"scene.load" = []', r"'scene\.load' must list at least one value"),
    ('"load" = [1]', r"cannot vary 'load': name scene\.PARAMETER"),
    ('"simulate.azimuths" = [4]', r"case azimuths=4: mi-nest simulate: unrecognized arguments: --azimuths 4"),
    ('"simulate.res" = ["big"]', r"mi-nest simulate: argument --res: invalid int value: 'big'"),
    ('"simulate.bands" = ["450 532", "450-532"]', r"cases \['bands=450-532'\] would share a directory"),
], ids=["unknown parameter", "empty range", "no section", "unknown option", "bad value", "same directory"])
def test_bad_sweep_files_are_refused_before_any_case(tmp_path, vary, refusal):
    path = _sweep_file(tmp_path, vary)
    with pytest.raises(SweepError, match=refusal):
        read_sweep(path, _argument_problem)
    assert main(["sweep", str(path), "-o", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()


def test_a_sweep_of_a_scene_that_does_not_exist_or_an_unknown_section_is_refused(tmp_path, capsys):
    missing = tmp_path / "missing.toml"
    missing.write_text('scene = "no_such_scene"\n')
    assert main(["sweep", str(missing), "-o", str(tmp_path / "out")]) == 2
    assert "no_such_scene" in capsys.readouterr().err
    extra = tmp_path / "extra.toml"
    extra.write_text('scene = "disk_compression"\n[reconstruction]\niterations = 3\n')
    assert main(["sweep", str(extra), "-o", str(tmp_path / "out")]) == 2
    assert "unknown section(s) ['reconstruction']" in capsys.readouterr().err
    assert main(["sweep", str(tmp_path / "absent.toml"), "-o", str(tmp_path / "out")]) == 2
    assert "sweep file not found" in capsys.readouterr().err


def test_ctrl_c_keeps_the_finished_cases_and_leaves_no_process_behind(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    import psutil
    path = _sweep_file(tmp_path, '"scene.load" = [20, 30, 40, 50]')
    output = tmp_path / "out"
    run = subprocess.Popen([sys.executable, "-m", "mi_nest.cli", "sweep", str(path), "-o", str(output),
                            "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not list(output.glob("cases/*/row.json")) and time.monotonic() < deadline and run.poll() is None:
        time.sleep(0.1)
    run.send_signal(signal.SIGINT)
    _, error = run.communicate(timeout=120)
    assert run.returncode == 130, error
    assert error.strip().splitlines()[-1] == ("mi-nest: interrupted; the finished cases are kept: run the same "
                                              "command again to run the others")
    finished = sorted(p.parent.name for p in output.glob("cases/*/row.json"))
    assert 1 <= len(finished) < 4
    # The cases' own processes ended with their workers.
    time.sleep(1)
    assert not [p for p in psutil.process_iter(["cmdline"]) if str(output) in " ".join(p.info["cmdline"] or [])]
    assert main(["sweep", str(path), "-o", str(output), "--no-progress"]) == 0
    rows = _rows(output)
    assert len(rows) == 4 and all(r["status"] == "done" for r in rows)


def test_the_accuracy_suite_as_a_sweep_runs_the_suite_s_own_commands(tmp_path, monkeypatch):
    from pathlib import Path

    from mi_nest.cli import _parser
    root = Path(__file__).resolve().parents[1]
    monkeypatch.syspath_prepend(str(root / "benchmarks"))
    import accuracy_suite as suite
    sweep = read_sweep(root / "experiments" / "sweeps" / "accuracy_suite.toml", _argument_problem)
    assert [case.name for case in sweep.cases] == [case.name for case in suite.CASES]
    captured = {}

    def run_command(command, arguments):
        captured[command] = arguments
        return 0.0
    monkeypatch.setattr(suite, "run_command", run_command)
    (tmp_path / "reconstruction.json").write_text("{}")
    for listed, case in zip(sweep.cases, suite.CASES):
        suite.simulate(case, Path("DATA"), case.rotations, case.res)
        suite.reconstruct(case, Path("DATA"), tmp_path, 10, 200)
        theirs = {"simulate": captured["simulate"],
                  "reconstruct": [a if a != str(tmp_path) else "OUT" for a in captured["reconstruct"]]}
        ours = {"simulate": [*listed.simulate, "-o", "DATA"],
                "reconstruct": ["DATA", "-o", "OUT", "--no-progress", *listed.reconstruct]}
        for command in ("simulate", "reconstruct"):
            parsed = [vars(_parser().parse_args([command, *arguments]))
                      for arguments in (ours[command], theirs[command])]
            if command == "reconstruct":    # the suite restarts a case it reruns; a sweep never reruns a finished one
                parsed[1]["restart"] = parsed[0]["restart"]
            assert parsed[0] == parsed[1], (case.name, command)


def test_listed_cases_cross_the_varied_values(tmp_path):
    path = tmp_path / "listed.toml"
    path.write_text(TINY.replace("{vary}", '"reconstruct.option.seed" = [0, 1]') + '''
[[cases]]
name = "light"
"scene.load" = 20

[[cases]]
scene = "stacked_disks"
"scene.load" = 30
''')
    sweep = read_sweep(path, _argument_problem)
    assert [case.name for case in sweep.cases] == ["light_seed=0", "light_seed=1", "load=30_seed=0", "load=30_seed=1"]
    assert sweep.columns == ["scene.load", "scene", "reconstruct.option.seed"]
    assert sweep.varied == ["reconstruct.option.seed"] and sweep.listed
    assert sweep.cases[2].simulate[0] == "stacked_disks" and "load=30" in sweep.cases[2].simulate
    assert sweep.cases[3].values == {"scene": "stacked_disks", "scene.load": 30, "reconstruct.option.seed": 1}
    path.write_text(TINY.replace("{vary}", "") + '[[cases]]\n"scene.load" = [20, 30]\n')
    with pytest.raises(SweepError, match=r"a listed case gives 'scene.load' one value, not \[20, 30\]"):
        read_sweep(path, _argument_problem)


@pytest.mark.parametrize("name, cases", [("accuracy_suite", 17), ("rotation_range", 3), ("stress_optic", 3),
                                         ("forward_models", 3), ("network_learning_rate", 7), ("mlp_learning_rate", 12),
                                         ("relative_smoothness", 4)])
def test_the_shipped_sweep_files_read(name, cases):
    from pathlib import Path
    sweep = read_sweep(Path(__file__).resolve().parents[1] / "experiments" / "sweeps" / f"{name}.toml",
                       _argument_problem)
    assert len(sweep.cases) == cases and len({case.name for case in sweep.cases}) == cases
