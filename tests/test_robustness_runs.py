"""Issue 18 ("Trust"), item 4 (locked output directories) and item 5 (interruptions and limits).

Real processes, real signals, real files: a second process holds the lock, SIGINT
reaches a running ``mi-nest``, a writer is killed with SIGKILL mid-write.
"""
import json
import re
import resource
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import mi_nest
from mi_nest.cli import INTERRUPTED_STATUS, main
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.dataset import format as fmt
from mi_nest.io.atomic import TEMPORARY_MARK, atomic_path
from mi_nest.io.lock import LOCK_FILE, DirectoryInUseError, locked_directory
from mi_nest.reconstruct import CheckpointError, optimize
from scenes import GENTLE, TINY

FAST = dict(iterations=3, batch_size=64, views_per_batch=3, resolution=6, evaluate_views=1, pixel_samples=1)
# Not messages about how a run ended: tqdm's progress lines (carriage returns between updates), warnings, what
# --yes tells the operator.
PROGRESS = re.compile(r"^\s*(render|simulate|acquire|reconstruct)\b.*\||^\s*$|^mi-nest: warning: |^\[--yes\] ")


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    directory = tmp_path_factory.mktemp("data") / "disk"
    simulate("disk_compression", directory, TINY, progress=False, defines=GENTLE)
    return directory


def _scene():
    return mi_nest.load_scene("disk_compression", res=8, **GENTLE)


def _command(*args, **options):
    return subprocess.Popen([sys.executable, "-m", "mi_nest.cli", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **options)


def _messages(stderr):
    """stderr's lines but progress bars, warnings and notes to the operator."""
    return [line.strip() for line in re.split(r"[\r\n]", stderr) if not PROGRESS.match(line)]


def _holder(directory):
    """A second process that takes ``directory``'s lock and keeps it until killed."""
    script = ("import sys, time\nfrom mi_nest.io.lock import locked_directory\n"
              "with locked_directory(sys.argv[1]):\n    print('held', flush=True)\n    time.sleep(120)\n")
    holder = subprocess.Popen([sys.executable, "-c", script, str(directory)], stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline() == "held\n"
    return holder


RIG = """[devices]
azimuth = "aptsim://azimuth"
elevation = "aptsim://elevation"
qwp2 = "ell14sim://qwp2"

[camera]
kind = "twin"
scene = "disk_compression"
resolution = [16, 16]
supersample = 1
exposure = 0.05

[schedule]
azimuths = {azimuths}
elevations = {elevations}
"""


def _rig(tmp_path, azimuths=2, elevations=2):
    path = tmp_path / f"rig_{azimuths}x{elevations}.toml"
    path.write_text(RIG.format(azimuths=azimuths, elevations=elevations))
    return path


# --- item 4: one writer per output directory ------------------------------------------------------
def test_a_second_writer_is_refused_while_another_process_holds_the_directory(tiny_dataset, tmp_path, capsys):
    """Item 4 (locking): simulate, reconstruct and acquire refuse a directory another run holds, naming it."""
    busy = tmp_path / "busy"
    holder = _holder(busy)
    try:
        with pytest.raises(DirectoryInUseError, match=rf"{busy} is in use by another run \(PID {holder.pid} "):
            simulate("disk_compression", busy, TINY, progress=False, defines=GENTLE)
        for command in (["simulate", "disk_compression", "-o", busy, "--azimuth", "2", "--elevation", "2"],
                        ["reconstruct", tiny_dataset, "--allow-aliased",
                         "-o", busy, "--iterations", "2", "--no-progress"],
                        ["acquire", _rig(tmp_path), "-o", busy, "--yes", "--quiet", "--unverified-handedness"]):
            assert main(list(map(str, command))) == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and f"in use by another run (PID {holder.pid}" in err, err
        assert [p.name for p in busy.iterdir()] == [LOCK_FILE]     # nothing was written beside the lock
    finally:
        holder.kill()
        holder.wait()
    # The holder died without releasing anything: the OS did, and its lock file is no obstacle.
    report = simulate("disk_compression", busy, TINY, progress=False, defines=GENTLE)
    assert report.rendered == 4 and not (busy / LOCK_FILE).exists()


def test_a_run_locks_a_directory_again_inside_itself_and_leaves_no_trace(tmp_path):
    """Item 4 (locking): the lock is re-entrant within one process, and a run that wrote nothing leaves nothing."""
    directory = tmp_path / "result"
    with locked_directory(directory):
        with locked_directory(directory):
            assert (directory / LOCK_FILE).is_file()
        assert (directory / LOCK_FILE).is_file()
    assert not directory.exists()


# --- item 5: Ctrl-C ---------------------------------------------------------------------------------
def _interrupt(args, ready, delay):
    """Start ``mi-nest args``, wait for ``ready(stderr so far)`` then ``delay`` s, send SIGINT.

    Returns ``(exit code, stderr, seconds from SIGINT to exit)``.
    """
    process = _command(*args)
    stderr = []
    reader = threading.Thread(target=lambda: stderr.extend(iter(lambda: process.stderr.read(1), "")), daemon=True)
    reader.start()
    deadline = time.monotonic() + 60
    while not ready("".join(stderr)):
        assert process.poll() is None, f"mi-nest ended before it was interrupted: {''.join(stderr)}"
        assert time.monotonic() < deadline
        time.sleep(0.01)
    time.sleep(delay)
    process.send_signal(signal.SIGINT)
    sent = time.monotonic()
    process.wait(timeout=30)
    seconds = time.monotonic() - sent
    reader.join(timeout=5)
    return process.returncode, "".join(stderr), seconds


@pytest.mark.parametrize("delay", [0.0, 0.13, 0.37])
def test_ctrl_c_in_reconstruct_writes_the_checkpoint_it_names(tiny_dataset, tmp_path, delay):
    """Item 5 (Ctrl-C): reconstruct ends with one line, exit 130, and a checkpoint of the iteration it stopped at.

    Before, about one Ctrl-C in six landed inside a Dr.Jit loop: a RuntimeError traceback and no checkpoint.
    """
    output = tmp_path / "result"
    code, err, seconds = _interrupt(["reconstruct", tiny_dataset, "--allow-aliased",
                                     "-o", output, "--iterations", "1000000",
                                     "--option", "batch_size=64", "--resolution", "6", "--no-progress"],
                                    lambda _: (output / "checkpoint.npz").is_file(), delay)
    messages = _messages(err)
    assert code == INTERRUPTED_STATUS and "Traceback" not in err, err
    assert len(messages) == 1, err
    stopped = re.fullmatch(r"mi-nest: interrupted; stopped after iteration (\d+), checkpoint in (.+); run it again "
                           r"to resume from there", messages[0])
    assert stopped and stopped.group(2) == str(output / "checkpoint.npz"), messages
    with np.load(output / "checkpoint.npz") as checkpoint:
        # The first checkpoint (iteration 100) was on disk before the signal; this one is where it stopped.
        assert int(checkpoint["iteration"]) == int(stopped.group(1)) >= 100
        assert len(json.loads(str(checkpoint["history"]))) == int(stopped.group(1))
    assert seconds < 3, seconds


@pytest.mark.parametrize("command, ready, kept", [
    (["render", "disk_compression", "-o", "{tmp}/disk.exr", "-D", "res=512", "-D", "spp=64"], "render:", None),
    (["simulate", "disk_compression", "-o", "{tmp}/dataset", "--azimuth", "12", "--elevation", "12", "--res", "64"],
     "simulate:", "the rotations written so far are kept"),
    (["acquire", "{rig}", "-o", "{tmp}/capture", "--yes", "--unverified-handedness"], "acquire:",
     "every journaled frame is kept"),
], ids=["render", "simulate", "acquire"])
def test_ctrl_c_ends_a_command_with_one_line(command, ready, kept, tmp_path):
    """Item 5 (Ctrl-C): render, simulate and acquire end within a second or two, one line, exit 130."""
    rig = _rig(tmp_path, 10, 10)
    args = [a.format(tmp=tmp_path, rig=rig) for a in command]
    for delay in (0.0, 0.3):
        code, err, seconds = _interrupt(args, lambda err: ready in err, delay)
        assert code == INTERRUPTED_STATUS and "Traceback" not in err, err
        assert _messages(err) == ["mi-nest: interrupted" + (f"; {kept}: run the same command again to resume"
                                                            if kept else "")], err
        assert seconds < 3, seconds
    if command[0] == "simulate":
        report = simulate("disk_compression", tmp_path / "dataset", SimulationSettings(azimuths=12, elevations=12,
                                                                                        res=64), progress=False)
        assert report.kept > 0 and report.kept + report.rendered == 144


# A Ctrl-C whose handler runs inside a finalizer: Python would print the KeyboardInterrupt there with a traceback and
# drop it (seen once in CI: `acquire` interrupted while a ZipFile was collected).
INTERRUPTED_IN_A_FINALIZER = """
import signal, time
from mi_nest import interrupts
class Finalized:
    def __del__(self):
        signal.raise_signal(signal.SIGINT)      # the handler runs at the next call, still inside __del__
        sum(range(10))
try:
    with interrupts.handling():
        Finalized()
        for _ in range(300):
            time.sleep(0.01)
    print("not interrupted")
except KeyboardInterrupt:
    print("interrupted, counted", interrupts.received())
"""


def test_a_ctrl_c_that_lands_in_a_finalizer_is_not_lost_and_prints_no_traceback():
    ran = subprocess.run([sys.executable, "-c", INTERRUPTED_IN_A_FINALIZER], capture_output=True, text=True,
                         timeout=60)
    assert ran.stdout.strip() == "interrupted, counted True", (ran.stdout, ran.stderr)
    assert "Traceback" not in ran.stderr and "Exception ignored" not in ran.stderr, ran.stderr


# --- item 5: limits ---------------------------------------------------------------------------------
@pytest.mark.filterwarnings("ignore:photoelastic. fringes denser")     # 8x8 pixels: said, not the point here
def test_a_step_size_with_too_many_steps_per_ray_is_refused_with_the_numbers(tmp_path, capsys):
    """Item 5 (limits): step 1e-9 mm rendered an all-zero retardance (the step count overflowed); now refused."""
    assert main(["render", "disk_compression", "-o", str(tmp_path / "x.exr"), "-D", "res=8", "-D", "step=1e-9",
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "step_size 1e-09 mm makes up to 5.69e+10 steps per ray" in err, err
    assert "bounding box diagonal is 56.89 mm" in err and "use a step_size of at least 5.7e-05 mm" in err
    with pytest.raises(ValueError, match="steps per ray"):
        mi_nest.render(mi_nest.load_scene("disk_compression", res=8, step=1e-5))
    # At the limit's side that is allowed, the answer is the converged one.
    fine = mi_nest.render(mi_nest.load_scene("disk_compression", res=8, spp=1, step=1e-4))
    coarse = mi_nest.render(mi_nest.load_scene("disk_compression", res=8, spp=1, step=0.5))
    np.testing.assert_allclose(fine.channels["char.delta"], coarse.channels["char.delta"], atol=1e-3)


TOO_LARGE = r"a 1000000x1000000 render .* needs about 4.\d+e\+05 GiB; [\d.]+ GiB are available"


@pytest.mark.parametrize("res, message, simulated", [
    ("0", "the film is 0x0 pixels", "'res' must be a positive integer, got 0"),
    ("1000000", TOO_LARGE, TOO_LARGE),
])
def test_empty_or_absurd_images_are_refused_in_one_line(res, message, simulated, tmp_path, capsys):
    """Item 5 (limits): res 0 and 10^6 gave Dr.Jit tracebacks; now one line each, before any work."""
    assert main(["render", "disk_compression", "-o", str(tmp_path / "x.exr"), "-D", f"res={res}", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err), err
    assert main(["simulate", "disk_compression", "-o", str(tmp_path / "data"), "--res", res]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(simulated, err), err
    assert not (tmp_path / "data").exists()


def test_an_image_larger_than_the_memory_limit_is_refused_and_a_smaller_one_renders(tmp_path):
    """Item 5 (limits): under an address-space limit a 3000x3000 render died in a NumPy MemoryError inside
    Dr.Jit (a traceback; larger ones segfaulted); now it is refused with the numbers, a small one still renders."""
    limit = 3 * 2 ** 30

    def limited():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    big = _command("render", "disk_compression", "-o", tmp_path / "big.exr", "-D", "res=3000", "--quiet",
                   preexec_fn=limited)
    _, err = big.communicate(timeout=120)
    assert big.returncode == 2 and "Traceback" not in err, err
    assert re.fullmatch(r"mi-nest: error: a 3000x3000 render of 27 channels at 1 sample\(s\) per pixel per pass "
                        r"needs about [\d.]+ GiB; [\d.]+ GiB are available: lower the resolution or the samples "
                        r"per pixel \(spp\)\n", err), err
    small = _command("render", "disk_compression", "-o", tmp_path / "small.exr", "-D", "res=64", "--quiet",
                     preexec_fn=limited)
    out, err = small.communicate(timeout=120)
    assert small.returncode == 0 and (tmp_path / "small.exr").is_file(), err


# --- item 5: temporary files of killed runs -------------------------------------------------------
def test_temporary_files_of_a_killed_writer_are_removed_by_the_next_write(tmp_path):
    """Item 5 (temporary files): a writer killed mid-write leaves its temporary file; the next write of the same
    file removes it, and leaves a running writer's alone."""
    target = tmp_path / "dataset.json"
    script = ("import sys, time\nfrom mi_nest.io.atomic import atomic_path\n"
              "with atomic_path(sys.argv[1], '.json') as tmp:\n    open(tmp, 'w').write('{\"half')\n"
              "    print('writing', flush=True)\n    time.sleep(120)\n")
    writers = [subprocess.Popen([sys.executable, "-c", script, str(target)], stdout=subprocess.PIPE, text=True)
               for _ in range(2)]
    try:
        for writer in writers:
            assert writer.stdout.readline() == "writing\n"
        killed, running = writers
        killed.kill()
        killed.wait()
        left = [p.name for p in tmp_path.iterdir()]
        assert len(left) == 2 and all(name.startswith(f".dataset.json{TEMPORARY_MARK}") for name in left)
        live = next(name for name in left if f"{TEMPORARY_MARK}{running.pid}-" in name)
        with atomic_path(target, ".json") as tmp:
            with open(tmp, "w") as handle:
                handle.write("{}")
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["dataset.json", live])
    finally:
        for writer in writers:
            writer.kill()
            writer.wait()


# --- item 5: corrupt checkpoints and frames -------------------------------------------------------
@pytest.mark.parametrize("damage", ["truncated", "garbage", "incomplete"])
def test_a_corrupt_checkpoint_gets_one_line_naming_restart(tiny_dataset, tmp_path, capsys, damage):
    """Item 5 (corrupt files): a damaged checkpoint was a BadZipFile traceback; now one line naming --restart."""
    output = tmp_path / "result"
    arguments = ["reconstruct", str(tiny_dataset), "--allow-aliased",
                 "-o", str(output), "--iterations", "2", "--option", "batch_size=64",
                 "--resolution", "6", "--no-progress"]
    assert main(arguments) == 0
    checkpoint = output / "checkpoint.npz"
    if damage == "truncated":
        checkpoint.write_bytes(checkpoint.read_bytes()[:checkpoint.stat().st_size // 2])
    elif damage == "garbage":
        checkpoint.write_bytes(np.random.default_rng(0).bytes(4096))
    else:
        np.savez(checkpoint, iteration=np.array(5))
    capsys.readouterr()
    assert main(arguments) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{checkpoint} is not a " in err and err.endswith("; add --restart to start "
                                                                                       "over\n"), err
    with pytest.raises(CheckpointError, match="pass resume=False to start over"):
        optimize(_scene(), tiny_dataset, output=output, progress=False, **FAST)
    assert main(arguments + ["--restart"]) == 0


def test_a_damaged_journaled_frame_is_captured_again(tmp_path, capsys, caplog):
    """Item 5 (corrupt files): a journaled frame whose file is damaged was a BadZipFile traceback on resume;
    now the journal forgets it and the run captures it again."""
    from mi_nest.rig.acquire import read_journal
    capture = tmp_path / "capture"
    arguments = ["acquire", str(_rig(tmp_path)), "-o", str(capture), "--yes", "--quiet", "--unverified-handedness"]
    assert main(arguments) == 0
    # A crash after rotation 1's last frame was committed, before its EXR was assembled; a frame then damaged.
    (capture / fmt.rotation_file(1)).unlink()
    _, frames = read_journal(capture / "journal.jsonl")
    damaged = next(record for record in frames.values() if record["rotation"] == 1)
    frame = capture / damaged["file"]
    frame.write_bytes(frame.read_bytes()[:100])
    capsys.readouterr()
    assert main(arguments) == 0
    assert f"1 frames captured, {len(frames) - 1} kept from an earlier run" in capsys.readouterr().out
    assert f"cannot be read ({damaged['key']}); capturing them again" in caplog.text
    _, again = read_journal(capture / "journal.jsonl")      # each frame once
    assert set(again) == set(frames) and (capture / fmt.rotation_file(1)).is_file()
    assert len(mi_nest.Dataset(capture)) == 4
