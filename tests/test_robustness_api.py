"""Issue 18 ("Trust"), item 6 ("Smaller"): scenes print, wrong argument types are named where they are passed,
the end of input, shipped stress files by name, and command-line advice in command-line words."""
import subprocess
import sys

import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.reconstruct import FieldConfig, OptimizeConfig, optimize
from mi_nest.scene import scene_file
from scenes import TINY

FAST = dict(iterations=2, batch_size=64, views_per_batch=3, resolution=6, evaluate_views=1, pixel_samples=1)


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    directory = tmp_path_factory.mktemp("data") / "disk"
    simulate("disk_compression", directory, TINY, progress=False, defines={"load": 20})
    return directory


@pytest.mark.parametrize("name, specimen", [("disk_compression", "StressMedium[C="),
                                            ("kitten", "Specimen[filename=")])
def test_a_scene_prints_with_every_plugin(name, specimen):
    """Item 6: str(scene) and repr(scene) raised AttributeError (notebooks display scenes)."""
    scene = mi_nest.load_scene(name, res=8)
    for text in (str(scene), repr(scene)):
        assert "PhotoelasticIntegrator[method=product, step_size=" in text
        assert "PolariscopeLight[" in text and "PolariscopeCamera[" in text and specimen in text


@pytest.mark.parametrize("options, error, message", [
    ({"passes": 0}, ValueError, "'passes' must be a positive integer, got 0"),
    ({"passes": 2.5}, TypeError, r"'passes' must be an integer, got 2.5 \(float\)"),
    ({"spp": "4"}, TypeError, r"'spp' must be an integer, got '4' \(str\)"),
    ({"spp": True}, TypeError, r"'spp' must be an integer, got True \(bool\)"),
    ({"seed": -1}, ValueError, "'seed' must be an integer >= 0, got -1"),
])
def test_render_names_a_wrong_argument(options, error, message):
    """Item 6: render(passes=0) was a ZeroDivisionError from inside; every argument is checked where passed."""
    scene = mi_nest.load_scene("disk_compression", res=8)
    with pytest.raises(error, match=message):
        mi_nest.render(scene, **options)


def test_optimize_refuses_a_fractional_iteration_count_before_any_work(tiny_dataset):
    """Item 6: optimize(iterations=2.5) ran 3 iterations; config integers are integers."""
    with pytest.raises(TypeError, match=r"'iterations' must be an integer, got 2.5 \(float\)"):
        optimize(mi_nest.load_scene("disk_compression", res=8, load=20), tiny_dataset, progress=False,
                 **{**FAST, "iterations": 2.5})
    for make, name, value in ((OptimizeConfig, "batch_size", True), (OptimizeConfig, "seed", 0.0),
                              (FieldConfig, "resolution", 8.0), (SimulationSettings, "azimuths", 2.5)):
        with pytest.raises(TypeError, match=f"'{name}' must be an integer"):
            make(**{name: value})
    with pytest.raises(ValueError, match="'evaluate_views' must be an integer >= 0, got -1"):
        OptimizeConfig(evaluate_views=-1)


@pytest.mark.parametrize("command", ["acquire", "calibrate"])
def test_waiting_for_an_operator_who_is_not_there_is_one_line(command, tmp_path):
    """Item 6: without --yes at the end of input (no terminal) acquire was an EOFError traceback."""
    run = subprocess.run([sys.executable, "-m", "mi_nest.cli", command, "rig_twin", "-o",
                          str(tmp_path / "out"), "--unverified-handedness" if command == "acquire" else
                          "--skip-handedness"], stdin=subprocess.DEVNULL, capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 2 and "Traceback" not in run.stderr, run.stderr
    errors = [line for line in run.stderr.splitlines() if line.startswith("mi-nest: error:")]
    assert errors == ["mi-nest: error: the run waits for the operator at the manual QWP1, but its input has ended "
                      "(no terminal); pass --yes to run unattended"], run.stderr


def test_export_finds_a_shipped_stress_file_from_anywhere(tmp_path, monkeypatch, capsys):
    """Item 6: `mi-nest export kitten.stress` (the README's line) worked only from scenes/data/."""
    monkeypatch.chdir(tmp_path)
    assert main(["export", "kitten.stress", "-o", "kitten.vtu"]) == 0
    assert "(17260 nodes, 14410 cells)" in capsys.readouterr().out
    assert (tmp_path / "kitten.vtu").stat().st_size > 100_000
    assert main(["export", "nowhere.stress", "-o", "x.vtu"]) == 2
    assert "stress file not found: nowhere.stress" in capsys.readouterr().err


def test_command_line_users_are_told_about_restart_not_resume_false(tiny_dataset, tmp_path, capsys):
    """Item 6: the checkpoint of another run told CLI users to 'pass resume=False'; they are told --restart."""
    output = tmp_path / "result"
    arguments = ["reconstruct", str(tiny_dataset), "--allow-aliased",
                 "-o", str(output), "--option", "batch_size=64", "--resolution", "6",
                 "--no-progress"]
    assert main(arguments + ["--iterations", "2"]) == 0
    capsys.readouterr()
    assert main(arguments + ["--iterations", "3"]) == 2
    err = capsys.readouterr().err
    assert "is a checkpoint of another run" in err and err.endswith("add --restart to start over\n"), err
    assert "resume=False" not in err
    with pytest.raises(ValueError, match="another run .*; pass resume=False to start over"):
        optimize(mi_nest.load_scene("disk_compression", res=8, load=20), tiny_dataset, output=output,
                 progress=False, **{**FAST, "iterations": 3})
    assert main(arguments + ["--iterations", "3", "--restart"]) == 0


def test_a_shipped_scene_name_is_found_beside_a_folder_of_that_name(tmp_path, monkeypatch):
    """`mi-nest simulate kitten -o kitten` (in a folder where `kitten/` exists, or is made by the run itself)
    said "scene file not found: kitten": a directory is no scene file."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "disk_compression").mkdir()
    assert scene_file("disk_compression") == mi_nest.scene_path("disk_compression").resolve()
    (tmp_path / "mine.xml").write_text("<scene version='3.0.0'/>")
    assert scene_file("mine.xml") == (tmp_path / "mine.xml").resolve()
