"""Failures that were tracebacks or messages that did not name the problem, found by an adversarial run: each is
one line now, saying what is wrong and how to fix it, with nothing written.

Real limits, real files: a file-size limit (``RLIMIT_FSIZE``) and an address-space limit (``RLIMIT_AS``) set in
the ``mi-nest`` subprocess, ``/dev/full`` for a full disk, a FIFO, a file another user may not read.
"""
import contextlib
import io
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.dataset import simulate
from mi_nest.io.atomic import TEMPORARY_MARK, OutOfRoomError, atomic_path
from mi_nest.reconstruct import Reconstruction, ReconstructionFileError, optimize
from scenes import GENTLE, TINY

FAST = dict(iterations=2, batch_size=64, views_per_batch=3, resolution=6, evaluate_views=1, pixel_samples=1)
NO_SENSOR = """<scene version="3.0.0">
    <integrator type="photoelastic"/>
    <emitter type="polariscope_light"/>
    <shape type="cube">
        <medium type="stress" name="interior">
            <float name="stress_optic_coefficient" value="50"/>
            <string name="model" value="uniform"/>
        </medium>
    </shape>
</scene>"""


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    directory = tmp_path_factory.mktemp("data") / "disk"
    simulate("disk_compression", directory, TINY, progress=False, defines=GENTLE)
    return directory


def _command(*args, limit=None, user=None, cwd=None):
    """``mi-nest args`` in a subprocess, under ``limit`` ``(resource, bytes)`` or as ``user`` (a uid); returns
    ``(exit code, stderr)``."""
    def prepare():
        if limit is not None:
            resource.setrlimit(limit[0], (limit[1], limit[1]))
        if user is not None:
            os.setgid(user)
            os.setuid(user)
    run = subprocess.run([sys.executable, "-m", "mi_nest.cli", *map(str, args)], capture_output=True, text=True,
                         timeout=300, preexec_fn=prepare, cwd=cwd)
    return run.returncode, run.stderr


def _error(stderr):
    """The one ``mi-nest: error:`` line of ``stderr`` (progress bars and warnings aside), asserting it is alone."""
    assert "Traceback" not in stderr, stderr
    errors = [line for line in re.split(r"[\r\n]", stderr) if line.startswith("mi-nest: error: ")]
    assert len(errors) == 1, stderr
    return errors[0][len("mi-nest: error: "):]


def _temporaries(directory):
    return [path for path in Path(directory).rglob("*") if TEMPORARY_MARK in path.name]


# --- full disks and file-size limits ----------------------------------------------------------------
FILE_TOO_LARGE = (r"cannot write {}: file too large: this process may write files of up to 20 KiB \(ulimit -f\); "
                  r"raise the limit or write a smaller file")


def test_a_file_size_limit_in_render_or_simulate_is_one_line_naming_the_file(tmp_path):
    """A file-size limit (or a full disk) in `render` or `simulate` was a RuntimeError traceback from the EXR
    writer naming its temporary file; now one line naming the file and the cause, and no part of it is left. A
    rerun with other settings is not refused by the dataset.json the failed simulate left (no rotation in it)."""
    limit = (resource.RLIMIT_FSIZE, 20 * 1024)
    code, err = _command("render", "disk_compression", "-D", "res=64", "-o", tmp_path / "image.exr", "--quiet",
                         limit=limit)
    assert code == 2 and re.fullmatch(FILE_TOO_LARGE.format(re.escape(str(tmp_path / "image.exr"))), _error(err))
    assert list(tmp_path.iterdir()) == []
    data = tmp_path / "data"
    code, err = _command("simulate", "disk_compression", "-o", data, "--res", "64", "--azimuth", "2", "--elevation",
                         "2", "--spp", "1", "-D", "load=20", limit=limit)
    rotation = re.escape(str(data / "rotations")) + r"/000\d\.exr"
    assert code == 2 and re.fullmatch(FILE_TOO_LARGE.format(rotation), _error(err))
    assert not _temporaries(data) and not list((data / "rotations").iterdir())
    code, err = _command("simulate", "disk_compression", "-o", data, "--res", "16", "--azimuth", "2", "--elevation",
                         "2", "--spp", "1", "-D", "load=20")
    assert code == 0, err
    assert json.loads((data / "dataset.json").read_text())["resolution"] == [16, 16]


def _on_a_full_disk(tmp_path, *commands):
    """Run ``mi-nest`` ``commands`` (each an argument list, ``DISK`` standing for the full disk's directory) in a
    mount namespace of their own, on a 64 KiB tmpfs filled to the brim; ``(exit codes, stderrs, what the disk
    holds at the end)``. Skips where mounting is not permitted (needs root, or user namespaces)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    runs = "".join(f'{sys.executable} -m mi_nest.cli {" ".join(map(str, command))} 2>"{tmp_path}/err{i}"; '
                   f'echo $? >"{tmp_path}/code{i}"; ' for i, command in enumerate(commands)).replace("DISK", str(disk))
    script = (f'mount -t tmpfs -o size=64k tmpfs "{disk}" || exit 99; head -c 1000000 /dev/zero >"{disk}/filler" '
              f'2>/dev/null; {runs}ls -A "{disk}"')
    run = subprocess.run(["unshare", "--mount", "sh", "-c", script], capture_output=True, text=True, timeout=300)
    if run.returncode:
        pytest.skip(f"cannot mount a small file system here: {run.stderr.strip()}")
    return ([int((tmp_path / f"code{i}").read_text()) for i in range(len(commands))],
            [(tmp_path / f"err{i}").read_text() for i in range(len(commands))], run.stdout.split())


@pytest.mark.filterwarnings("ignore:photoelastic. fringes denser")
def test_a_full_disk_is_one_line_naming_the_file(tmp_path):
    """A render to a full disk: a large image was OpenEXR's RuntimeError traceback; a small one (that OpenEXR
    kept in its buffer) was published EMPTY without a word. Both are one line naming the file and the space
    left now, and no file is left. /dev/full (ENOSPC to every write) shows Python's writes named the same way."""
    codes, errs, held = _on_a_full_disk(tmp_path, *(["render", "disk_compression", "-D", f"res={res}", "-o",
                                                     f"DISK/image{res}.exr", "--quiet"] for res in (4, 64)))
    for res, code, err in zip((4, 64), codes, errs):
        assert code == 2 and _error(err) == (f"cannot write {tmp_path}/disk/image{res}.exr: no space left on the "
                                             "device (0 bytes free); free some space or write elsewhere"), err
    assert held == ["filler"]
    target = tmp_path / "field.npz"
    with pytest.raises(OutOfRoomError, match=rf"^cannot write {re.escape(str(target))}: no space left on the device "
                                             r"\([\d.]+ [KMG]iB free\); free some space or write elsewhere$"):
        with atomic_path(target, ".npz") as tmp:
            os.unlink(tmp)
            os.symlink("/dev/full", tmp)
            np.savez(tmp, stress=np.zeros(100_000))
    assert not target.exists() and not _temporaries(tmp_path)


# --- memory --------------------------------------------------------------------------------------------
MEMORY = (resource.RLIMIT_AS, 3 * 2 ** 30)
GIB = r"needs about [\d.e+]+ GiB; [\d.]+ GiB are available: "


def test_work_that_cannot_fit_in_memory_is_refused_up_front_with_the_numbers(tiny_dataset, tmp_path):
    """export --resolution, slice --res and reconstruct's batch_size died in NumPy's ArrayMemoryError (a
    traceback); sizes that cannot fit are refused before any work, with the numbers, as render refuses images."""
    cases = [(["export", "disk_compression", "--resolution", "2000", "-o", tmp_path / "field.vtu"],
              r"an export at resolution 2000 \(1204000000 grid nodes in 1 specimen\(s\)\) " + GIB
              + r"lower the resolution \(mi-nest export --resolution\)"),
             (["slice", "disk_compression", "--plane", "z=0", "--thickness", "1", "--res", "20000",
               "-o", tmp_path / "slice.exr"],
              r"a 20000x20000 slice " + GIB + r"lower the resolution \(mi-nest slice --res\)"),
             (["reconstruct", tiny_dataset, "--allow-aliased", "-o", tmp_path / "result", "--option",
               "batch_size=100000000", "--iterations", "2", "--resolution", "6", "--no-progress"],
              r"a batch of 100000000 pixels, 1 ray\(s\) each, " + GIB
              + r"lower batch_size \(mi-nest reconstruct --option batch_size=N\) or pixel_samples")]
    for arguments, message in cases:
        code, err = _command(*arguments, limit=MEMORY)
        assert code == 2 and re.fullmatch(message, _error(err)), err
    assert list(tmp_path.iterdir()) == []


def test_running_out_of_memory_where_nothing_estimated_it_is_one_line(tmp_path):
    """Any MemoryError left (here `principal --res 30000`, which no estimate guards) is one line with what to
    lower, not a traceback."""
    code, err = _command("principal", "disk_compression", "--plane", "z=0", "--res", "30000",
                         "-o", tmp_path / "principal.png", limit=MEMORY)
    assert code == 2 and re.fullmatch(r"out of memory \(Unable to allocate [\d.]+ GiB for an array with shape "
                                      r".*\): lower --res, or free some memory", _error(err)), err
    assert list(tmp_path.iterdir()) == []


# --- tracebacks from inside -------------------------------------------------------------------------------
def test_a_scene_without_a_sensor_is_refused_by_name(tmp_path, capsys):
    """A scene with no sensor was an IndexError from scene.sensors()[0]."""
    path = tmp_path / "no_sensor.xml"
    path.write_text(NO_SENSOR)
    message = f'{path} has no sensor: add a <sensor type="polariscope"> (the camera and the polariscope\'s ' \
              "analysing side) to it"
    with pytest.raises(mi_nest.SceneError, match=re.escape(message)):
        mi_nest.render(mi_nest.load_scene(path))
    for command in (["render", path, "-o", tmp_path / "image.exr"],
                    ["slice", path, "--plane", "z=0", "--thickness", "0.5", "-o", tmp_path / "slice.exr"]):
        assert main(list(map(str, command))) == 2
        assert capsys.readouterr().err == f"mi-nest: error: {message}\n"
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_a_dataset_without_one_of_its_channels_is_refused_by_name(tiny_dataset, tmp_path, capsys):
    """A channel removed from dataset.json was an IndexError in the metrics at the end of a reconstruction."""
    damaged = tmp_path / "damaged"
    shutil.copytree(tiny_dataset, damaged)
    index = json.loads((damaged / "dataset.json").read_text())
    index["channels"].remove("pol.45.0.0")
    (damaged / "dataset.json").write_text(json.dumps(index))
    message = (f"{damaged}/dataset.json: corrupt: 'channels' must list each of the 16 measurements "
               "(pol.<b1>.<b2>.<a2>) once; it lists 15, without ['pol.45.0.0']: put the dataset's own dataset.json "
               "back, or simulate or acquire it again")
    with pytest.raises(mi_nest.DatasetError, match=re.escape(message)):
        mi_nest.Dataset(damaged)
    assert main(["reconstruct", str(damaged), "--allow-aliased", "-o", str(tmp_path / "result"), "--iterations", "2",
                 "--no-progress"]) == 2
    assert capsys.readouterr().err == f"mi-nest: error: {message}\n"
    assert not (tmp_path / "result").exists()


@pytest.mark.filterwarnings("ignore:photoelastic. fringes denser")     # the shipped disk at 256x256
def test_render_takes_a_scene_name_and_names_a_wrong_field():
    """mi_nest.render("disk_compression") and render(scene, field="junk") were AttributeErrors from inside: a
    name or path is loaded, a field that is no StressField is refused naming what it takes."""
    assert mi_nest.render("disk_compression", spp=1).main.shape == (256, 256)
    with pytest.raises(TypeError, match=r"^'field' must be a StressField \(a reconstruction's .field, or one of "
                                        r"mi_nest.fields\) to render in every specimen, or None for their own "
                                        r"stress; got 'junk' \(str\)$"):
        mi_nest.render(mi_nest.load_scene("disk_compression", res=8), field="junk")
    with pytest.raises(TypeError, match=r"'scene' must be a scene \(mi_nest.load_scene\(...\)\) or a scene file or "
                                        r"shipped scene name, got 3 \(int\)"):
        mi_nest.render(3)


# --- messages that did not name the problem ---------------------------------------------------------------
def _as_nobody(arguments):
    """``(exit code, stderr)`` of ``mi-nest arguments`` run by ``main`` in a forked child that is nobody (uid
    65534) when this process is root (who may read any file), this user otherwise."""
    read, write = os.pipe()
    child = os.fork()
    if child == 0:      # the child reports through the pipe and ends without running pytest's cleanup
        try:
            os.close(read)
            if os.geteuid() == 0:
                os.setgroups([])
                os.setgid(65534)
                os.setuid(65534)
            with contextlib.redirect_stderr(io.StringIO()) as stderr:
                code = main(list(map(str, arguments)))
            os.write(write, json.dumps([code, stderr.getvalue()]).encode())
        finally:
            os._exit(0)
    os.close(write)
    with os.fdopen(read) as pipe:
        report = pipe.read()
    os.waitpid(child, 0)
    return json.loads(report)


def test_an_unreadable_scene_file_is_named_as_such():
    """A scene file this user may not read was reported as Mitsuba's "File was not found"."""
    folder = Path(tempfile.mkdtemp())       # not under pytest's private temporary directory: nobody enters it
    try:
        folder.chmod(0o755)
        scene = folder / "scene.xml"
        shutil.copy(mi_nest.scene_path("disk_compression"), scene)
        scene.chmod(0o000)
        code, err = _as_nobody(["render", scene, "-o", folder / "image.exr", "-D", "res=8"])
        assert code == 2 and err == (f"mi-nest: error: {scene}: permission denied: this user may not read the scene "
                                     "file; check its permissions\n")
        assert [p.name for p in folder.iterdir()] == ["scene.xml"]
    finally:
        shutil.rmtree(folder)


def test_a_fifo_given_as_scene_is_named_as_such(tmp_path, monkeypatch, capsys):
    """A FIFO given as the scene was reported as "no shipped scene 'pipe.xml'" (opening it would have hung)."""
    monkeypatch.chdir(tmp_path)
    os.mkfifo("pipe.xml")
    for scene in ("pipe.xml", str(tmp_path / "pipe.xml")):
        assert main(["render", scene, "-o", "image.exr"]) == 2
        assert capsys.readouterr().err == (f"mi-nest: error: {scene} is a named pipe (FIFO), not a scene file; give "
                                           "a scene XML file\n")


@pytest.mark.parametrize("arguments, message", [
    (["-o", "."], "-o . is a directory; give a file to write, such as NAME.exr"),
    (["-o", "image.exr", "--png", "."], "--png . is a directory; give a file to write, such as NAME.png"),
])
def test_a_directory_as_output_file_is_refused_before_rendering(arguments, message, tmp_path, monkeypatch, capsys):
    """`-o .` was "Device or resource busy" (after the render) and `--png .` "unknown file extension:" (after the
    EXR was written); both are refused before anything renders or is written."""
    monkeypatch.chdir(tmp_path)
    assert main(["render", "disk_compression", "-D", "res=8", "--quiet", *arguments]) == 2
    assert capsys.readouterr().err == f"mi-nest: error: {message}\n"
    assert list(tmp_path.iterdir()) == []


def test_export_names_the_inputs_it_takes(tmp_path, capsys):
    """A .msh (or any unknown suffix) given to export was parsed as a scene XML ("No document element found")."""
    mesh = tmp_path / "part.msh"
    mesh.write_text("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n")
    assert main(["export", str(mesh), "-o", str(tmp_path / "part.vtu")]) == 2
    assert capsys.readouterr().err == (
        f"mi-nest: error: {mesh}: mi-nest export takes a stress file (grid or mesh .npz, 3D-TSV .TSV/.stress or "
        ".TSVcarti/.carti), a scene (.xml file or shipped name) or a reconstruction directory, not a '.msh' file (a "
        "mesh holds no stress: solve it with mi-nest fem MESH --fix WHERE --load WHERE:FX,FY,FZ -o part.npz and "
        "export part.npz)\n")
    assert [p.name for p in tmp_path.iterdir()] == ["part.msh"]


@pytest.mark.parametrize("minutes", ["-1", "0", "nan"])
def test_minutes_must_be_positive_in_the_words_of_the_flag(minutes, tiny_dataset, tmp_path, capsys):
    """--minutes -1 was "'time_limit' must be a positive number of seconds, got -60.0": not the flag typed."""
    assert main(["reconstruct", str(tiny_dataset), "--allow-aliased", "-o", str(tmp_path / "result"), "--minutes",
                 minutes, "--no-progress"]) == 2
    assert capsys.readouterr().err == f"mi-nest: error: --minutes must be a positive number of minutes, got {minutes}\n"
    assert not (tmp_path / "result").exists()


def test_a_damaged_reconstruction_file_is_named_with_what_to_do(tiny_dataset, tmp_path, capsys):
    """A damaged reconstruction.json was a bare JSON message ("Expecting property name ..."), a damaged field.npz
    a BadZipFile traceback; both name the file, say it is damaged and what to do; so does a damaged trust.npz."""
    result = tmp_path / "result"
    optimize(mi_nest.load_scene("disk_compression", res=8, **GENTLE), tiny_dataset, output=result, progress=False,
             **FAST)
    record = (result / "reconstruction.json").read_bytes()
    (result / "reconstruction.json").write_bytes(record[:100])
    advice = "restore it from a copy, or run the mi-nest reconstruct command that wrote it again"
    message = rf"{re.escape(str(result))}/reconstruction.json is damaged and cannot be read \(Expecting .*\); {advice}"
    with pytest.raises(ReconstructionFileError, match=message):
        Reconstruction.load(result)
    assert main(["render", str(result), "-o", str(tmp_path / "view.exr"), "--quiet"]) == 2
    assert re.fullmatch(message, _error(capsys.readouterr().err))
    (result / "reconstruction.json").write_bytes(record)
    field = (result / "field.npz").read_bytes()
    (result / "field.npz").write_bytes(field[:300])
    with pytest.raises(ReconstructionFileError, match=rf"field.npz is damaged and cannot be read \(.*\); {advice}"):
        Reconstruction.load(result)
    (result / "field.npz").write_bytes(field)
    (result / "trust.npz").write_bytes((result / "trust.npz").read_bytes()[:300])
    assert main(["principal", str(result), "--plane", "z=0", "--res", "8", "-o", str(tmp_path / "p.png")]) == 2
    assert re.fullmatch(rf"{re.escape(str(result))}/trust.npz is damaged and cannot be read \(.*\); delete it to go "
                        "on without the trust map, or run the mi-nest reconstruct command that wrote it again",
                        _error(capsys.readouterr().err))
    assert not (tmp_path / "p.png").exists()


def test_a_refused_simulate_writes_nothing_and_the_corrected_rerun_runs(tmp_path, capsys):
    """A simulate refused at its first render (a stress of 1e15 MPa) left a stub dataset.json that refused the
    corrected rerun ("holds a dataset made with other settings (source)"); now it writes nothing."""
    data = tmp_path / "data"
    arguments = ["simulate", "disk_compression", "-o", str(data), "--res", "8", "--azimuth", "2", "--elevation", "2",
                 "--spp", "1"]
    assert main(arguments + ["-D", "load=1e15"]) == 2
    assert "pixels are NaN or inf" in _error(capsys.readouterr().err)
    assert not data.exists()
    assert main(arguments + ["-D", "load=20"]) == 0
    assert (data / "rotations" / "0003.exr").is_file()
