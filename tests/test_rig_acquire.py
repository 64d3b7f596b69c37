"""Journaled acquisition and calibration on the digital twin: the dataset equals a simulation of the same
scene, interruptions and device faults lose or duplicate no frame, and calibration finds the twin's offsets."""
import dataclasses
import json
import shutil
import warnings

import numpy as np
import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.dataset import format as fmt
from mi_nest.io.exr import read_channels
from mi_nest.physics.bands import parse_bands
from mi_nest.physics.su2 import identity
from mi_nest.rig import sim
from mi_nest.rig.acquire import (JOURNAL, AcquisitionError, acquire, dry_run, estimate_seconds, read_journal,
                                 schedule)
from mi_nest.rig.config import RigConfigError, load, parse
from mi_nest.rig.sim.protocol_aptsim import COUNTS_PER_DEGREE

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")
DEFINES = {"load": 150, "contact_width": 4}
URLS = {"azimuth": "aptsim://azimuth", "elevation": "aptsim://elevation", "qwp2": "ell14sim://qwp2"}


@pytest.fixture(autouse=True)
def fresh_simulation():
    sim.reset()
    yield
    sim.reset()


def rig_file(tmp_path, resolution=16, azimuths=2, elevations=2, optics=None, model=None, scene="disk_compression",
             extra="", bands=None):
    """A rig TOML for an ideal (or given) twin (a colour camera's with ``bands``), written to ``tmp_path``."""
    def table(name, values):
        return f"[{name}]\n" + "".join(f"{k} = {json.dumps(v) if isinstance(v, bool) else repr(v)}\n"
                                       for k, v in (values or {}).items())
    camera = {"kind": "twin", "scene": scene, "resolution": [resolution, resolution], "supersample": 1, "spp": 1}
    if bands is not None:
        camera["bands"] = bands
    text = (extra + table("devices", URLS) + table("camera", camera)
            + table("camera.defines", DEFINES) + table("camera.optics", optics) + table("camera.model", model)
            + table("schedule", {"azimuths": azimuths, "elevations": elevations, "azimuth_range": 180.0,
                                 "elevation_range": 90.0, "test_fraction": 0.25})
            + table("timing", {"settle": 0.2}))
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def journal_keys(directory):
    lines = (directory / JOURNAL).read_text().splitlines()
    return [json.loads(line)["key"] for line in lines[1:]]


def rotation_channels(directory):
    dataset = mi_nest.Dataset(directory)
    return [dataset.view(i, list(fmt.CHANNELS) + ["mask.dolp"]) for i in range(len(dataset))], dataset


def assert_same_dataset(a, b):
    views_a, dataset_a = rotation_channels(a)
    views_b, dataset_b = rotation_channels(b)
    assert len(views_a) == len(views_b)
    for va, vb in zip(views_a, views_b):
        for name in va:
            np.testing.assert_array_equal(va[name], vb[name], err_msg=name)
    for i in range(len(dataset_a)):
        np.testing.assert_array_equal(dataset_a.to_world(i), dataset_b.to_world(i))


def test_a_twin_capture_is_the_simulated_dataset_and_reconstructs(tmp_path):
    config = load(rig_file(tmp_path))
    report = acquire(config, tmp_path / "captured", progress=False, unverified_handedness=True)
    assert report.captured == len(schedule(config)) == 16 and report.kept == 0
    captured = mi_nest.Dataset(tmp_path / "captured")
    assert captured.index["source"]["kind"] == "captured" and captured.index["complete"]
    assert captured.index["mask_channels"] == ["mask.dolp"] and captured.index["calibration"] is None
    assert len(captured) == 4 and captured.channels == fmt.CHANNELS
    assert "mask.occupancy" not in read_channels(tmp_path / "captured" / fmt.rotation_file(0))

    settings = SimulationSettings(azimuths=2, elevations=2, azimuth_range=180.0, elevation_range=90.0, res=16, spp=1,
                                  test_fraction=0.25)
    simulate("disk_compression", tmp_path / "simulated", settings, defines=DEFINES, progress=False)
    simulated = mi_nest.Dataset(tmp_path / "simulated")
    for i in range(4):
        assert captured.rotations[i]["split"] == simulated.rotations[i]["split"]
        np.testing.assert_array_equal(captured.to_world(i), simulated.to_world(i))
        ours, theirs = captured.view(i), simulated.view(i)
        assert max(ours[n].max() for n in fmt.CHANNELS) > 0.1
        for name in fmt.CHANNELS:
            np.testing.assert_allclose(ours[name], theirs[name], atol=1e-3, err_msg=name)
        np.testing.assert_array_equal(captured.view(i, ["mask.dolp"])["mask.dolp"],
                                      simulated.view(i, ["mask.dolp"])["mask.dolp"])
        measured = captured.rotations[i]["measured"]
        assert measured["azimuth"] == [captured.rotations[i]["azimuth"]] * 4

    result = mi_nest.optimize(mi_nest.load_scene("disk_compression", res=16, spp=1, **DEFINES), captured,
                              iterations=2, progress=False, truth=None)
    assert result is not None


def test_a_colour_twin_capture_is_the_simulated_dataset_in_bands_and_reconstructs(tmp_path):
    """A colour camera's frames (each analyser image one per band) assemble into the dataset ``mi-nest simulate
    --bands`` writes of the same scene: the same channels, bands and values."""
    config = load(rig_file(tmp_path, bands="450,532,650"))
    acquire(config, tmp_path / "captured", progress=False, unverified_handedness=True)
    with np.load(tmp_path / "captured" / "frames" / f"{journal_keys(tmp_path / 'captured')[0]}.npz") as frame:
        assert frame["analyzer_0"].shape == (3, 16, 16)
    captured = mi_nest.Dataset(tmp_path / "captured")
    bands = parse_bands("450,532,650")
    settings = SimulationSettings(azimuths=2, elevations=2, azimuth_range=180.0, elevation_range=90.0, res=16, spp=1,
                                  test_fraction=0.25, bands=bands)
    simulate("disk_compression", tmp_path / "simulated", settings, defines=DEFINES, progress=False)
    simulated = mi_nest.Dataset(tmp_path / "simulated")
    assert captured.channels == simulated.channels == fmt.measurement_channels(bands)
    assert captured.bands.names == ("450", "532", "650") and captured.channel_bands() == simulated.channel_bands()
    for i in range(4):
        ours, theirs = captured.view(i), simulated.view(i)
        for name in captured.channels:
            np.testing.assert_allclose(ours[name], theirs[name], atol=1e-3, err_msg=name)
        np.testing.assert_array_equal(captured.view(i, ["mask.dolp"])["mask.dolp"],
                                      simulated.view(i, ["mask.dolp"])["mask.dolp"])
    # The bands differ where the specimen is (the disk at 150 N shows about a fringe at its centre).
    view = captured.view(0)
    assert np.abs(view["450.pol.45.0.45"] - view["650.pol.45.0.45"]).max() > 0.05
    result = mi_nest.optimize(mi_nest.load_scene("disk_compression", res=16, spp=1, **DEFINES), captured,
                              iterations=2, progress=False, truth=None)
    assert result is not None


@pytest.mark.parametrize("mirrored", [False, True])
def test_a_colour_twin_with_the_colour_mosaic_calibrates_and_checks_its_handedness(tmp_path, capsys, mirrored):
    """The IMX250MYR's mosaic (one colour filter per polariser cell) and RGB curves: calibration finds the twin's
    offsets from every band's free-space images, and the handedness check, predicting each band of the known
    specimen, passes the rig as built and catches a mirrored one."""
    optics = {"analyzer_offset": 0.6, "qwp1_offset": -0.9, "qwp2_offset": 2.3, "mirrored": mirrored}
    path = rig_file(tmp_path, resolution=32, optics=optics, bands="rgb",
                    model={"read_noise": 0.01, "bits": 12, "seed": 3, "mosaic": True})
    code = main(["calibrate", str(path), "-o", str(tmp_path / "calibration.json"), "--yes"])
    if mirrored:
        assert code == 2 and "the capture matches a mirrored rig" in capsys.readouterr().err
        return
    assert code == 0
    calibration = json.loads((tmp_path / "calibration.json").read_text())
    for name in ("analyzer_offset", "qwp1_offset", "qwp2_offset"):
        assert abs(calibration["optics"][name] - optics[name]) < 0.2, name
    handedness = calibration["handedness"]
    assert handedness["verified"] and handedness["found"] == "as built" and handedness["margin"] > 10, handedness


def test_an_interrupted_capture_resumes_without_losing_or_repeating_a_frame(tmp_path):
    config = load(rig_file(tmp_path))
    acquire(config, tmp_path / "reference", progress=False, unverified_handedness=True)
    keys = [frame.key for frame in schedule(config)]

    def stop_after(count):
        def on_frame(record):
            if record["frame"] + 1 == count:
                raise KeyboardInterrupt
        return on_frame

    output = tmp_path / "interrupted"
    with pytest.raises(KeyboardInterrupt):
        acquire(config, output, progress=False, unverified_handedness=True, on_frame=stop_after(5))
    assert journal_keys(output) == keys[:5]
    assert not mi_nest.Dataset(output, allow_incomplete=True).index["complete"]
    # a frame written but not committed, and a journal line torn by a crash, are both redone
    shutil.copy(output / "frames" / f"{keys[0]}.npz", output / "frames" / f"{keys[5]}.npz")
    with open(output / JOURNAL, "a") as journal:
        journal.write('{"key": "' + keys[5])
    with pytest.raises(KeyboardInterrupt):
        acquire(config, output, progress=False, unverified_handedness=True, on_frame=stop_after(11))
    assert journal_keys(output) == keys[:11]
    report = acquire(config, output, progress=False, unverified_handedness=True)
    assert (report.captured, report.kept) == (5, 11)
    assert journal_keys(output) == keys
    assert_same_dataset(output, tmp_path / "reference")


def test_device_faults_are_survived_and_measured_positions_recorded(tmp_path):
    config = load(rig_file(tmp_path))
    offset_counts = 7         # within the HDR50 driver's tolerance: the move is accepted, the truth is recorded

    def on_frame(record):
        if record["frame"] == 2:
            sim.device(URLS["azimuth"]).inject("dropped_byte")
            sim.device(URLS["elevation"]).inject("busy")
            sim.device(URLS["qwp2"]).inject("busy")
            sim.device(URLS["qwp2"]).inject("dropped_byte")
        if record["frame"] == 5:
            sim.device(URLS["azimuth"]).inject("disconnect_mid_move")
        if record["frame"] == 9:
            sim.device(URLS["elevation"]).inject("position_offset", counts=offset_counts)

    retried = []

    def on_retry(frame, error, attempt):
        retried.append((frame.key, type(error).__name__))
        sim.device(URLS["azimuth"]).disconnected = False      # the cable goes back in

    output = tmp_path / "faulty"
    report = acquire(config, output, progress=False, unverified_handedness=True,
                     on_frame=on_frame, on_retry=on_retry)
    assert retried and all(kind == "CommunicationError" for _, kind in retried)
    assert report.retries == len(retried)
    assert journal_keys(output) == [frame.key for frame in schedule(config)]
    _, records = read_journal(output / JOURNAL)
    off = [r for r in records.values()
           if abs(r["elevation"] - r["elevation_nominal"]) > 0.5 / COUNTS_PER_DEGREE]
    assert len(off) == 1 and off[0]["frame"] == 10
    assert off[0]["elevation"] == pytest.approx(off[0]["elevation_nominal"] + offset_counts / COUNTS_PER_DEGREE,
                                                abs=1e-9)
    dataset = mi_nest.Dataset(output)
    entry = dataset.rotations[off[0]["rotation"]]
    assert entry["elevation"] == pytest.approx(np.mean(entry["measured"]["elevation"]))
    assert entry["elevation"] != entry["nominal"]["elevation"]


def test_a_frame_that_keeps_failing_stops_the_run_with_the_journal_intact(tmp_path):
    config = load(rig_file(tmp_path))
    output = tmp_path / "broken"

    def on_frame(record):
        if record["frame"] == 3:
            sim.device(URLS["qwp2"]).inject("disconnect_mid_move")     # and nobody plugs it back in

    with pytest.raises(AcquisitionError, match="failed 4 times.*run the same command again to resume"):
        acquire(config, output, progress=False, unverified_handedness=True, on_frame=on_frame)
    assert journal_keys(output) == [frame.key for frame in schedule(config)][:4]
    sim.device(URLS["qwp2"]).disconnected = False
    report = acquire(config, output, progress=False, unverified_handedness=True)
    assert (report.captured, report.kept) == (12, 4)
    assert mi_nest.Dataset(output).index["complete"]


def test_dry_run_prints_the_schedule_and_its_duration(tmp_path, capsys):
    assert main(["acquire", str(rig_file(tmp_path)), "-o", str(tmp_path / "unused"), "--dry-run"]) == 0
    printed = capsys.readouterr().out
    assert "4 rotations" in printed and "16 frames" in printed and "64 analyser images" in printed
    assert "frame 0: 0000.45.0" in printed and "estimated duration" in printed
    assert not (tmp_path / "unused").exists()

    paper = load(rig_file(tmp_path, azimuths=25, elevations=16))     # the paper's 400 rotations
    seconds = dry_run(paper, out=lambda line: None)
    frames = schedule(paper)
    assert len(frames) == 1600 and seconds == estimate_seconds(paper, frames)
    slower = dataclasses.replace(paper, timing=dataclasses.replace(paper.timing, settle=paper.timing.settle + 1))
    assert estimate_seconds(slower, frames) == pytest.approx(seconds + len(frames))


@pytest.mark.parametrize("change, message", [
    (lambda t: t.replace("[devices]", "[devices]\nfocus = 'aptsim://f'"), r"\[devices\] has unknown key.*focus"),
    (lambda t: t.replace("azimuth = 'aptsim://azimuth'", ""), r"\[devices\] is missing 'azimuth'"),
    (lambda t: t.replace("kind = 'twin'", "kind = 'aravis'"), r"'twin' \(the digital twin\) or 'genicam'"),
    (lambda t: t.replace("'aptsim://azimuth'", "'/dev/ttyUSB0'"), "must be azimuth = aptsim://NAME"),
    (lambda t: t.replace("azimuths = 2", "azimuths = 0"), r"\[schedule\]: rotation count"),
    (lambda t: t.replace("[camera.model]", "[camera.model]\nnoise = 0.1"), r"\[camera.model\] has unknown key"),
    (lambda t: t + "[qwp1]\nmode = 'motorised'\n", "manual mount"),
    (lambda t: "calibration = 'nowhere.json'\n" + t, "calibration file not found"),
    (lambda t: t.replace("[camera]", "[camera]\nbands = '650,450'"), r"\[camera\] bands = '650,450': .*must increase"),
    (lambda t: t.replace("[camera]", "[camera]\nbands = 532"), r"\[camera\] bands must be a string"),
    (lambda t: t.replace("[camera]", "[camera]\nbands = 'curves.csv'"), r"\[camera\] bands = 'curves.csv'"),
    (lambda t: t.replace("[camera]", "[camera]\nbands = '450,650'").replace("[camera.model]",
                                                                          "[camera.model]\nmosaic = true"),
     "red, green and blue filters"),
])
def test_bad_rig_files_are_refused_with_the_key_named(tmp_path, change, message):
    path = rig_file(tmp_path)
    path.write_text(change(path.read_text().replace('"', "'")))
    with pytest.raises(RigConfigError, match=message):
        config = load(path)
        config.calibrated_optics()


def test_the_cli_reports_a_bad_rig_file(tmp_path, capsys):
    path = tmp_path / "rig.toml"
    path.write_text("[devices]\n")
    assert main(["acquire", str(path), "-o", str(tmp_path / "out")]) == 2
    assert "missing" in capsys.readouterr().err


def test_the_shipped_twin_rig_file_loads():
    config = load("rig_twin")
    assert config.camera.defines == DEFINES and config.camera.resolution == (32, 32)
    assert len(config.schedule.rotations()) == 16


def test_calibrate_finds_the_twins_offsets_and_acquisition_applies_them(tmp_path, capsys):
    optics = {"analyzer_offset": 0.6, "qwp1_offset": -0.9, "qwp2_offset": 2.3}
    path = rig_file(tmp_path, resolution=24, optics=optics, model={"read_noise": 0.01, "bits": 12, "seed": 3})
    assert main(["calibrate", str(path), "-o", str(tmp_path / "calibration.json"), "--yes"]) == 0
    assert "qwp2_offset = 2.3" in capsys.readouterr().out
    found = json.loads((tmp_path / "calibration.json").read_text())["optics"]
    for name, value in optics.items():
        assert abs(found[name] - value) < 0.2, name

    path.write_text('calibration = "calibration.json"\n' + path.read_text())
    config = load(path)
    output = tmp_path / "calibrated"
    acquire(config, output, progress=False)
    _, records = read_journal(output / JOURNAL)
    for record in records.values():
        assert record["qwp2_commanded"] == pytest.approx((record["qwp2"] - found["qwp2_offset"]) % 360)
        # the plate really sits there (to the ELL14's resolution)
        assert abs(record["qwp2_measured"] - record["qwp2_commanded"]) < 360 / 143360
    assert mi_nest.Dataset(output).index["calibration"]["qwp2_offset"] == pytest.approx(found["qwp2_offset"])


def test_a_calibrated_capture_is_read_through_the_polariscope_as_built(tmp_path):
    """The analyser cannot be turned and the waveplates are not exactly quarter-wave: the dataset's
    polariscopes (what reconstruction renders its channels with) are the calibrated ones, and they explain
    the background, where the Jones matrix is the identity, which the nominal ones do not."""
    optics = {"analyzer_offset": 3.0, "qwp1_retardance": 84.0, "qwp2_retardance": 96.0}
    path = rig_file(tmp_path, resolution=16, optics=optics)
    assert main(["calibrate", str(path), "-o", str(tmp_path / "calibration.json"), "--yes"]) == 0
    path.write_text('calibration = "calibration.json"\n' + path.read_text())
    acquire(load(path), tmp_path / "capture", progress=False)
    dataset = mi_nest.Dataset(tmp_path / "capture")
    scope = dataset.polariscopes()[dataset.channels.index("pol.45.0.45")]
    qwp2, analyzer = scope.camera
    assert analyzer.angle == pytest.approx(48.0, abs=0.05) and qwp2.retardance == pytest.approx(96.0, abs=0.1)

    def background_error():
        """Per channel, the median error over background pixels (some at the rim see the specimen)."""
        free = [s.intensity(identity(0.0)) for s in dataset.polariscopes()]
        background = [dataset.measurements(p)[dataset.view(p, ["mask.dolp"])["mask.dolp"] < 0.5]
                      for p in range(len(dataset))]
        return np.median(np.abs(np.concatenate(background) - free), axis=0).max()

    as_built = background_error()
    dataset.index["calibration"] = None
    assert as_built < 5e-3 < 0.02 < background_error()


@pytest.mark.slow
def test_soak_two_thousand_moves_with_random_faults(tmp_path):
    """672 frames, three moves each, with a random fault queued on a random device every few frames."""
    config = parse(_soak_table(), tmp_path / "rig.toml")
    frames = schedule(config)
    assert 3 * len(frames) >= 2000
    rng = np.random.default_rng(7)
    faults = {"aptsim": ("no_reply", "dropped_byte", "busy", "disconnect_mid_move", "position_offset"),
              "ell14sim": ("no_reply", "dropped_byte", "busy", "disconnect_mid_move", "mechanical_timeout")}
    injected = []

    def on_frame(record):
        if rng.random() < 0.3:
            url = list(URLS.values())[rng.integers(3)]
            fault = str(rng.choice(faults[url.split(":")[0]]))
            sim.device(url).inject(fault, **({"counts": 5} if fault == "position_offset" else {}))
            injected.append(fault)

    def on_retry(frame, error, attempt):
        for url in URLS.values():
            sim.device(url).disconnected = False

    output = tmp_path / "soak"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        report = acquire(config, output, progress=False, unverified_handedness=True,
                         on_frame=on_frame, on_retry=on_retry)
    assert len(injected) > 100 and report.retries > 10
    assert journal_keys(output) == [frame.key for frame in frames]
    assert mi_nest.Dataset(output).index["complete"]


def _soak_table():
    return {"devices": URLS,
            "camera": {"kind": "twin", "scene": "disk_compression", "resolution": [8, 8], "supersample": 1,
                       "defines": DEFINES},
            "schedule": {"azimuths": 12, "elevations": 14, "azimuth_range": 180.0, "elevation_range": 90.0},
            "acquisition": {"retries": 5}}
