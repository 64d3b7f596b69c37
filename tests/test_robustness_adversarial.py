"""Findings of an adversarial run: outputs written over inputs, a dataset resumed after its scene was edited, a
checkpoint of a replaced dataset, EXR bytes under another suffix, a rotation listed twice, NaN and negative rig
settings, a dataset that cannot fit, and a viewer port that hung the command."""
import json
import re
import resource
import shutil
import subprocess
import sys
import warnings

import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.dataset import DatasetError, simulate
from mi_nest.dataset import format as fmt
from mi_nest.io.exr import ExrFileError
from mi_nest.rig.config import RigConfigError, parse
from scenes import TINY, UNIFORM_CUBE_XML

try:
    import tomllib
except ModuleNotFoundError:     # Python < 3.11
    import tomli as tomllib

# A 6 mm cube of uniform stress, its specimen in a file of its own that the scene includes.
SCENE_XML = """<scene version="3.0.0">
    <default name="res" value="8"/>
    <integrator type="photoelastic"><float name="step_size" value="0.5"/></integrator>
    <emitter type="polariscope_light"><float name="polarizer" value="90"/></emitter>
    <sensor type="polariscope">
        <string name="projection" value="orthographic"/>
        <transform name="to_world"><scale x="4" y="4"/><lookat origin="0, 0, 50" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <sampler type="stratified"><integer name="sample_count" value="1"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="$res"/><integer name="height" value="$res"/>
            <string name="pixel_format" value="luminance"/><rfilter type="box"/>
        </film>
    </sensor>
    <include filename="part.xml"/>
</scene>"""
PART_XML = f"""<scene version="3.0.0">
{UNIFORM_CUBE_XML}</scene>"""


def cube_scene(directory, stress=1.0):
    """The cube scene in ``directory`` (scene.xml including part.xml); the scene's path."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "part.xml").write_text(PART_XML.format(stress=stress))
    (directory / "scene.xml").write_text(SCENE_XML)
    return directory / "scene.xml"


def simulated(scene, directory, **defines):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # 8x8 pixels: fringe aliasing is said, not the point
        return simulate(scene, directory, TINY, progress=False, defines=defines)


def errors(capsys):
    """The command's stderr, which must be one line."""
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mi-nest: error: ") and "Traceback" not in err, err
    return err.strip()


# ----------------------------------------------------------------------------------- outputs over inputs

@pytest.mark.parametrize("arguments, option, victim", [
    (["render", "{scene}", "-o", "{scene}"], "-o", "scene.xml"),
    (["render", "{scene}", "-o", "{tmp}/out.exr", "--png", "{scene}"], "--png", "scene.xml"),
    (["render", "{scene}", "-o", "{tmp}/part.xml"], "-o", "part.xml"),        # a file the scene includes
    (["slice", "{scene}", "--plane", "z=0", "--thickness", "1", "--res", "8", "-o", "{scene}"], "-o", "scene.xml"),
    (["principal", "{scene}", "--plane", "z=0", "--res", "8", "-o", "{scene}"], "-o", "scene.xml"),
    (["simulate", "{scene}", "-o", "{scene}"], "-o", "scene.xml"),
])
def test_an_output_that_is_an_input_is_refused_naming_both(tmp_path, capsys, arguments, option, victim):
    """Data loss: `mi-nest render my.xml -o my.xml` replaced the scene with the EXR, exit 0."""
    scene = cube_scene(tmp_path)
    before = {name: (tmp_path / name).read_bytes() for name in ("scene.xml", "part.xml")}
    given = [a.format(scene=scene, tmp=tmp_path) for a in arguments]
    assert main(given) == 2
    output = given[given.index(option) + 1]
    assert errors(capsys) == (f"mi-nest: error: {option} {output} would overwrite {tmp_path / victim}, an input of "
                              f"this command; give {option} another path")
    assert {name: (tmp_path / name).read_bytes() for name in before} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["part.xml", "scene.xml"]


def test_export_and_calibrate_refuse_to_overwrite_their_input(tmp_path, capsys):
    """The same for a stress file exported over itself and a rig file calibrated over itself."""
    stress = shutil.copy(mi_nest.scene_path("kitten").parent / "data" / "kitten.stress", tmp_path / "part.tsv")
    rig = shutil.copy(mi_nest.scene_path("kitten").parent / "rig_twin.toml", tmp_path / "rig.toml")
    before = {path: path.read_bytes() for path in (stress, rig)}
    assert main(["export", str(stress), "-o", str(stress)]) == 2
    assert errors(capsys) == (f"mi-nest: error: -o {stress} would overwrite {stress}, an input of this command; "
                              "give -o another path")
    assert main(["calibrate", str(rig), "-o", str(rig), "--yes"]) == 2
    assert errors(capsys) == (f"mi-nest: error: -o {rig} would overwrite {rig}, an input of this command; give -o "
                              "another path")
    assert {path: path.read_bytes() for path in before} == before


# ------------------------------------------------------------------------------ resuming an edited scene

@pytest.mark.parametrize("edited", ["scene.xml", "part.xml"])
def test_resuming_a_dataset_after_its_scene_was_edited_is_refused(tmp_path, capsys, edited):
    """Data loss: simulate killed, its scene edited, and the rerun kept the old scene's rotations beside the new
    ones, exit 0. The dataset records its scene files' content; a rerun with the files unchanged still resumes."""
    scene = cube_scene(tmp_path / "scene")
    dataset = tmp_path / "data"
    simulated(scene, dataset)
    assert simulated(scene, dataset).kept == 4
    recorded = json.loads((dataset / fmt.INDEX).read_text())["source"]["scene_content"]
    assert sorted(recorded) == [str(scene.parent / "part.xml"), str(scene)]
    path = scene.parent / edited
    path.write_text(path.read_text().replace('"1.0"', '"2.0"') if edited == "part.xml" else
                    path.read_text() + "<!-- edited -->\n")
    rotations = {p.name: p.read_bytes() for p in (dataset / "rotations").iterdir()}
    with pytest.raises(DatasetError, match="resuming would mix rotations of two scenes"):
        simulated(scene, dataset)
    assert main(["simulate", str(scene), "-o", str(dataset), "--azimuth", "2", "--elevation", "2", "--res", "8",
                 "--spp", "1", "--test-fraction", "0.25"]) == 2
    assert errors(capsys) == (f"mi-nest: error: {dataset} was simulated from {scene} before {path} changed; "
                              "resuming would mix rotations of two scenes: choose a new directory or delete it")
    assert {p.name: p.read_bytes() for p in (dataset / "rotations").iterdir()} == rotations


# ------------------------------------------------------------------------ the checkpoint of another dataset

@pytest.mark.filterwarnings("ignore::RuntimeWarning")     # 8x8 pixels: fringe aliasing is said, not the point
def test_a_checkpoint_of_a_replaced_dataset_is_not_resumed(tmp_path, capsys):
    """Silent wrong result: `reconstruct` rerun after the dataset at its path was replaced returned the old fit;
    the checkpoint named its dataset by path only. It records the dataset's content now."""
    scene = cube_scene(tmp_path / "scene")
    dataset, output = tmp_path / "data", tmp_path / "result"
    simulated(scene, dataset)
    arguments = ["reconstruct", str(dataset), "-o", str(output), "--iterations", "2", "--option", "batch_size=64",
                 "--resolution", "6", "--no-progress", "--no-truth"]
    assert main(arguments) == 0
    assert main(arguments) == 0             # the same dataset: resumed from the checkpoint
    capsys.readouterr()
    shutil.rmtree(dataset)
    simulated(cube_scene(tmp_path / "other", stress=3.0), dataset)
    assert main(arguments) == 2
    assert errors(capsys) == (f"mi-nest: error: {output / 'checkpoint.npz'} is a checkpoint of another run (the "
                              f"dataset at {dataset} as it was before it was replaced or changed); choose another "
                              "output directory; add --restart to start over")
    assert main(arguments + ["--restart"]) == 0


# ------------------------------------------------------------------------------ EXR under another suffix

@pytest.mark.parametrize("arguments", [
    ["render", "{scene}", "-o", "{tmp}/out.png"],
    ["slice", "{scene}", "--plane", "z=0", "--thickness", "1", "--res", "8", "-o", "{tmp}/out.png"],
])
def test_an_exr_output_must_be_named_exr(tmp_path, capsys, arguments):
    """Silent wrong result: `render ... -o out.png` wrote EXR bytes under a .png name."""
    scene = cube_scene(tmp_path)
    assert main([a.format(scene=scene, tmp=tmp_path) for a in arguments]) == 2
    assert errors(capsys) == (f"mi-nest: error: {tmp_path / 'out.png'}: the image is written as OpenEXR, so its "
                              "name must end in .exr (a PNG preview goes to --png NAME.png)")
    assert not (tmp_path / "out.png").exists()
    with pytest.raises(ExrFileError, match="must end in .exr"):
        mi_nest.render(mi_nest.load_scene(scene)).write_exr(tmp_path / "out.png")
    assert not (tmp_path / "out.png").exists()


# ---------------------------------------------------------------------------------- a rotation listed twice

@pytest.mark.parametrize("key, message", [("index", "rotation 1 is listed 2 times"),
                                          ("file", "rotation file rotations/0001.exr is listed 2 times")])
def test_a_rotation_listed_twice_is_refused(tmp_path, key, message):
    """Silent wrong result: a dataset.json listing one rotation twice was accepted (and trained on twice)."""
    dataset = tmp_path / "data"
    simulated(cube_scene(tmp_path / "scene"), dataset)
    index = json.loads((dataset / fmt.INDEX).read_text())
    index["rotations"][2][key] = index["rotations"][1][key]
    (dataset / fmt.INDEX).write_text(json.dumps(index))
    with pytest.raises(DatasetError, match=f"{dataset / fmt.INDEX}: {message} " + r"\(a dataset lists each "
                                           r"rotation once"):
        mi_nest.Dataset(dataset)


# --------------------------------------------------------------------------------------- rig settings

NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize("table, key, value, message", [
    ("camera", "exposure", -0.05, r"\[camera\] exposure must be a finite number > 0, got -0.05"),
    ("camera", "exposure", NAN, r"\[camera\] exposure must be a finite number > 0, got nan"),
    ("timing", "settle", NAN, r"\[timing\] settle must be a finite number, got nan"),
    ("timing", "settle", -1, r"\[timing\] settle must be a finite number >= 0, got -1"),
    ("timing", "stage_speed", INF, r"\[timing\] stage_speed must be a finite number, got inf"),
    ("camera.optics", "qwp1_offset", NAN, r"\[camera.optics\] qwp1_offset must be a finite number, got nan"),
    ("camera.model", "full_well", INF, r"\[camera.model\] full_well must be a finite number, got inf"),
    ("schedule", "azimuths", 2.5, r"\[schedule\] azimuths must be an integer, got 2.5"),
    ("schedule", "split_seed", NAN, r"\[schedule\] split_seed must be an integer, got nan"),
    ("acquisition", "retry_wait", -1, r"\[acquisition\] retry_wait must be a finite number >= 0, got -1"),
    ("acquisition", "dolp_threshold", 7, r"\[acquisition\] dolp_threshold is a degree of linear polarisation"),
    ("devices", "azimuth_channel", NAN, r"\[devices\] azimuth_channel must be an integer, got nan"),
])
def test_non_finite_or_negative_rig_settings_are_refused_naming_the_key(table, key, value, message):
    """Silent wrong result: calibrate took a negative exposure; NaN timings gave 'cannot convert float NaN to
    integer'."""
    data = tomllib.loads((mi_nest.scene_path("kitten").parent / "rig_twin.toml").read_text())
    section = data
    for name in table.split("."):
        section = section.setdefault(name, {})
    section[key] = value
    with pytest.raises(RigConfigError, match=message):
        parse(data)


def test_calibrate_refuses_a_negative_exposure_in_one_line_and_writes_nothing(tmp_path, capsys):
    rig = tmp_path / "rig.toml"
    rig.write_text((mi_nest.scene_path("kitten").parent / "rig_twin.toml").read_text().replace(
        "exposure = 0.05", "exposure = -0.05"))
    assert main(["calibrate", str(rig), "-o", str(tmp_path / "calibration.json"), "--yes"]) == 2
    assert errors(capsys) == f"mi-nest: error: {rig}: [camera] exposure must be a finite number > 0, got -0.05"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.toml"]


# --------------------------------------------------------------------------- a dataset that cannot fit

@pytest.mark.parametrize("arguments, message", [
    (["--azimuth", "100000", "--elevation", "100000", "--res", "8"],
     (r"a dataset of 10000000000 rotations \(100000 azimuths x 100000 elevations\) needs about 7.63e\+04 GiB of "
      r"memory for its index alone; [0-9.e+]+ GiB are available: simulate fewer rotations \(--azimuth, "
      r"--elevation\)")),
    (["--azimuth", "300", "--elevation", "200", "--res", "2048", "--float"],
     (r"a dataset of 60000 rotations \(300 azimuths x 200 elevations\) of 2048x2048 pixels needs up to 1.69e\+04 "
      r"GiB more on disk \(288 MiB per rotation file before compression\); [0-9.e+]+ GiB are free where .* is: "
      r"simulate fewer rotations \(--azimuth, --elevation\) or a lower resolution \(--res\)")),
])
def test_a_dataset_that_cannot_fit_is_refused_before_anything_is_allocated(tmp_path, arguments, message):
    """Hang: `simulate --azimuth 100000 --elevation 100000` grew to 8 GB without a word, listing its rotations.
    Run under an address-space limit, so that a regression fails fast instead of taking the machine's memory."""
    limit = 4 * 2 ** 30

    def limited():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    output = tmp_path / "data"
    run = subprocess.run([sys.executable, "-m", "mi_nest.cli", "simulate", str(cube_scene(tmp_path / "scene")),
                          "-o", str(output), "--spp", "1", *arguments], check=False, capture_output=True, text=True,
                         timeout=120, preexec_fn=limited)
    assert run.returncode == 2 and re.fullmatch("mi-nest: error: " + message + "\n", run.stderr), run.stderr
    assert not output.exists()


# --------------------------------------------------------------------------------------- the viewer's port

@pytest.mark.parametrize("arguments, message", [
    (["--port", "70000"], "mi-nest: error: '--port' must be an integer from 0 to 65535, got 70000"),
    (["--host", "192.0.2.1"], ("mi-nest: error: cannot serve on 192.0.2.1:8080 (Cannot assign requested address): "
                               "give --host an address of this machine (127.0.0.1, the default, serves this machine "
                               "only)")),
])
def test_a_viewer_that_cannot_serve_ends_in_one_line(arguments, message):
    """Hang: `mi-nest view --port 70000` printed the server thread's traceback and never exited (as did a host
    that is not this machine's: viser gave up on it and its start waited on)."""
    run = subprocess.run([sys.executable, "-m", "mi_nest.cli", "view", "disk_compression", "--no-browser",
                          *arguments], check=False, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and run.stderr == message + "\n", run.stderr
