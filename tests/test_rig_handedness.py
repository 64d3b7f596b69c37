"""Issue 18, item 1 (the rig): ``mi-nest calibrate`` checks the rig's handedness on a specimen of known stress,
and ``mi-nest acquire`` refuses a calibration whose handedness is not verified.

The twin is built with the faults free space cannot see (a mirrored rig, a waveplate with its axes swapped);
each must be caught and named, and the rig as built must pass."""
import json

import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.dataset import CameraModel
from mi_nest.rig import sim
from mi_nest.rig.acquire import TwinBackend, calibrate, dry_run
from mi_nest.physics.polariscope import ANALYZERS
from mi_nest.physics.su2 import identity
from mi_nest.rig.calibration import PARAMETERS, Exposure, _canonical, expected_exposures, fit
from mi_nest.rig.config import RigConfigError, load
from mi_nest.rig.handedness import MARGIN, HandednessError
from mi_nest.rig.twin import Optics, SimulatedCamera, free_space

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")
URLS = {"azimuth": "aptsim://azimuth", "elevation": "aptsim://elevation", "qwp2": "ell14sim://qwp2"}
# A realistic twin: offsets and retardances that calibration has to find, read noise, 12 bits and the mosaic.
OPTICS = {"analyzer_offset": 0.4, "qwp1_offset": -0.7, "qwp2_offset": 1.5, "qwp1_retardance": 88.0,
          "qwp2_retardance": 91.5}
MODEL = {"read_noise": 0.005, "bits": 12, "mosaic": True, "seed": 2}


@pytest.fixture(autouse=True)
def fresh_simulation():
    sim.reset()
    yield
    sim.reset()


def _toml(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{key} = {_toml(v)}" for key, v in value.items()) + "}"
    return json.dumps(value)


def error_lines(capsys):
    """What mi-nest printed on stderr, less the unattended operator's prompts."""
    return [line for line in capsys.readouterr().err.splitlines() if not line.startswith("[--yes]")]


def rig_file(tmp_path, faults=None, handedness=None, model=MODEL, calibration=None):
    """A 16x16 twin rig file (a 2x2 schedule) whose optics carry ``faults`` (``Optics`` fields)."""
    tables = {"devices": URLS,
              "camera": {"kind": "twin", "scene": "disk_compression", "resolution": [16, 16], "supersample": 1,
                         "spp": 1},
              "camera.defines": {"load": 150, "contact_width": 4},
              "camera.model": model, "camera.optics": {**OPTICS, **(faults or {})},
              "schedule": {"azimuths": 2, "elevations": 2, "azimuth_range": 180.0, "elevation_range": 90.0,
                           "test_fraction": 0.25},
              "timing": {"settle": 0.2}, "handedness": handedness or {}}
    text = "" if calibration is None else f"calibration = {_toml(str(calibration))}\n"
    for name, table in tables.items():
        text += f"[{name}]\n" + "".join(f"{key} = {_toml(value)}\n" for key, value in table.items())
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def free_space_sweep(optics, qwp2_angle=lambda reading: reading):
    """The calibration sweep's exposures on a noiseless 8x8 twin; ``qwp2_angle`` turns the ELL14's reading into
    the angle the plate really sits at."""
    state = {"qwp2": 0.0}
    twin = SimulatedCamera(free_space, lambda: (0.0, 0.0, qwp2_angle(state["qwp2"])), optics, CameraModel(), (8, 8))
    exposures = []
    for qwp1, qwp2 in expected_exposures():
        twin.qwp1, state["qwp2"] = qwp1, qwp2
        exposures.append(Exposure(qwp1, qwp2, twin.capture()))
    return exposures


def test_free_space_cannot_tell_a_mirrored_rig_or_conjugated_waveplates():
    """Item 1 (rig), the premise: a free-space sweep gives the same optics for the rig as built, a mirrored one
    and one with both waveplates swapped, so only a specimen of known stress can tell them apart."""
    reference = fit(free_space_sweep(Optics(**OPTICS)))
    for fault in ({"mirrored": True}, {"qwp1_swapped": True, "qwp2_swapped": True}):
        calibration = fit(free_space_sweep(Optics(**OPTICS, **fault)))
        assert calibration.optics == reference.optics and calibration.residual_rms < 1e-6
    # One swapped plate is seen, but not which one: the fit reports one plate swapped, offsets and retardances
    # found as they are.
    for fault in ({"qwp1_swapped": True}, {"qwp2_swapped": True}):
        optics = fit(free_space_sweep(Optics(**OPTICS, **fault))).optics
        assert optics.qwp1_swapped != optics.qwp2_swapped and not optics.mirrored
        for name in PARAMETERS:
            assert getattr(optics, name) == pytest.approx(OPTICS[name], abs=1e-3), name


@pytest.mark.parametrize("fitted, swapped", [
    ({"qwp2_offset": 91.5}, "qwp2"), ({"qwp1_retardance": -88.0}, "qwp1"), ({"qwp2_retardance": 268.5}, "qwp2"),
    ({"qwp2_retardance": 451.5}, None),
    ({"qwp1_offset": -90.7, "qwp2_retardance": -91.5}, None),
])
def test_the_calibration_reports_a_swapped_plate_in_one_form(fitted, swapped):
    """Item 1 (rig): whichever equivalent optics the fit lands on (a plate turned by 90 degrees, a negative or
    wrapped retardance), the calibration reports the same free-space polariscope as small offsets, positive
    retardances and at most one plate swapped."""
    found = Optics(**{**OPTICS, **fitted})
    canonical = _canonical(found)
    for name in PARAMETERS:
        assert getattr(canonical, name) == pytest.approx(OPTICS[name]), name
    assert [plate for plate in ("qwp1", "qwp2") if getattr(canonical, f"{plate}_swapped")] == ([swapped] if swapped
                                                                                              else [])
    for qwp1, qwp2 in expected_exposures():
        for analyzer in ANALYZERS:
            assert canonical.polariscope(qwp1, qwp2, analyzer).intensity(identity(0.0)) == pytest.approx(
                found.polariscope(qwp1, qwp2, analyzer).intensity(identity(0.0)), abs=1e-12)


def test_a_single_mount_turning_the_other_way_fails_the_free_space_fit():
    """Item 1 (rig): the ELL14 alone turning the other way (the plate at minus its reading) is no free-space
    symmetry: no polariscope fits the sweep, and the fit says so instead of returning optics 0.3 off."""
    exposures = free_space_sweep(Optics(**OPTICS), qwp2_angle=lambda reading: -reading)
    with pytest.raises(ValueError, match=r"no polariscope explains the free-space sweep \(residual rms 0\.[1-9]"):
        fit(exposures)


def test_the_twin_as_built_passes_and_the_calibration_records_it(tmp_path, capsys):
    """Item 1 (rig): ``mi-nest calibrate`` on the twin as built verifies the handedness on the oblique disk and
    writes the verification, with each hypothesis's residual and the margin, into the calibration JSON."""
    output = tmp_path / "calibration.json"
    assert main(["calibrate", str(rig_file(tmp_path)), "-o", str(output), "--yes"]) == 0
    captured = capsys.readouterr()
    assert "handedness verified on disk_compression" in captured.out
    assert "Put the specimen of known stress in view" in captured.err          # the operator was asked
    record = json.loads(output.read_text())["handedness"]
    assert record["verified"] is True and record["found"] == "as built"
    assert record["specimen"] == {"scene": "disk_compression",
                                  "defines": {"load": 150.0, "contact_width": 4.0,
                                              "load_direction": "-0.5, 0.8660254, 0"}}
    residuals = record["residuals"]
    assert set(residuals) == {"as built", "mirrored", "sign-flipped", "mirrored and sign-flipped"}
    # The right model leaves the camera's noise; every wrong one misses the fringes by far more.
    assert residuals["as built"] < 0.01 and min(v for k, v in residuals.items() if k != "as built") > 0.1
    assert record["margin"] == pytest.approx(sorted(residuals.values())[1] / residuals["as built"])
    assert record["margin"] > 10 * MARGIN and record["pixels"] > 100


@pytest.mark.parametrize("faults, found, check", [
    ({"mirrored": True}, "a mirrored rig", "does the ELL14 turn the other way"),
    ({"qwp1_swapped": True}, "a swapped QWP1", "QWP1's fast axis is 90 degrees from its mark"),
    ({"qwp2_swapped": True}, "a swapped QWP2", "QWP2's fast axis is 90 degrees from its mark"),
    ({"qwp1_swapped": True, "qwp2_swapped": True}, "a reversed stress sign", "both waveplates' fast-axis marks"),
    ({"mirrored": True, "qwp2_swapped": True}, "a mirrored rig and a swapped QWP2", "is the camera image flipped"),
])
def test_a_faulty_twin_is_caught_and_named(tmp_path, capsys, faults, found, check):
    """Item 1 (rig): a twin built mirrored, with QWP1 or QWP2 swapped, with both swapped (the stress sign
    reversed as the optics see it) or mirrored and swapped fails ``mi-nest calibrate`` with exit code 2 and one
    line naming what the capture matches and what to check; no calibration is written."""
    output = tmp_path / "calibration.json"
    assert main(["calibrate", str(rig_file(tmp_path, faults)), "-o", str(output), "--yes"]) == 2
    error = error_lines(capsys)
    assert len(error) == 1 and error[0].startswith("mi-nest: error: handedness check on disk_compression")
    assert f"the capture matches {found} (" in error[0] and check in error[0]
    assert not output.exists()


def test_an_unclear_capture_is_refused_with_its_margin(tmp_path, monkeypatch):
    """Item 1 (rig): when no hypothesis wins by the margin, the check refuses and reports the residuals and the
    margin it found: a camera too noisy to see the fringes, and an operator who never put the specimen in view."""
    unclear = (r"no clear answer \(residuals as built [0-9.]+, mirrored [0-9.]+, .*"
               rf"leads by [0-9.]+x, need {MARGIN:g}x\)")
    with pytest.raises(HandednessError, match=unclear):
        calibrate(load(rig_file(tmp_path, model={"read_noise": 0.15, "seed": 1})))
    sim.reset()
    monkeypatch.setattr(TwinBackend, "put_in_view", lambda backend, specimen: None)
    with pytest.raises(HandednessError, match=unclear + ": is the specimen in view"):
        calibrate(load(rig_file(tmp_path)))


def test_a_specimen_that_cannot_tell_the_rigs_apart_is_refused_before_the_operator_fetches_it(tmp_path):
    """Item 1 (rig): a specimen whose predictions hardly change between hypotheses (a disk loaded with 1 N) or
    that shows no birefringence is refused from the model alone, before the operator is asked to mount it."""
    asked = []
    for defines, message in (({"load": 1.0}, "looks the same to a rig"), ({"load": 0.0}, "shows no birefringence")):
        config = load(rig_file(tmp_path, handedness={"defines": defines}))
        with pytest.raises(HandednessError, match=message):
            calibrate(config, operator=asked.append)
        sim.reset()
    assert asked and not any("specimen" in message for message in asked)


def test_acquire_refuses_an_unverified_handedness_unless_told(tmp_path, capsys):
    """Item 1 (rig): ``mi-nest acquire`` refuses (one line, exit 2) a rig without a calibration, a calibration
    from before the check and one calibrated with --skip-handedness; with --unverified-handedness it captures,
    warns, and ``dataset.json`` says the handedness is unverified. A verified calibration is recorded as such."""
    calibration = tmp_path / "calibration.json"
    assert main(["calibrate", str(rig_file(tmp_path)), "-o", str(calibration), "--yes", "--skip-handedness"]) == 0
    assert json.loads(calibration.read_text())["handedness"]["verified"] is False
    old = tmp_path / "old.json"
    old.write_text(json.dumps({k: v for k, v in json.loads(calibration.read_text()).items() if k != "handedness"}))
    capsys.readouterr()
    for calibration_file, reason in ((None, "names no calibration"), (old, "predates the handedness check"),
                                     (calibration, "calibrated with --skip-handedness")):
        path = rig_file(tmp_path, calibration=calibration_file)
        assert main(["acquire", str(path), "-o", str(tmp_path / "refused"), "--yes", "--quiet"]) == 2
        error = error_lines(capsys)
        assert len(error) == 1 and "handedness is unverified" in error[0] and reason in error[0]
        assert "--unverified-handedness" in error[0] and not (tmp_path / "refused").exists()

    output = tmp_path / "unverified"
    with pytest.warns(UserWarning, match="capturing with an unverified handedness"):
        assert main(["acquire", str(path), "-o", str(output), "--yes", "--quiet", "--unverified-handedness"]) == 0
    assert mi_nest.Dataset(output).index["handedness"] == {"verified": False,
                                                          "reason": json.loads(calibration.read_text())
                                                          ["handedness"]["reason"]}

    assert main(["calibrate", str(path), "-o", str(calibration), "--yes"]) == 0
    assert main(["acquire", str(path), "-o", str(tmp_path / "verified"), "--yes", "--quiet"]) == 0
    record = mi_nest.Dataset(tmp_path / "verified").index["handedness"]
    assert record["verified"] is True and record["residuals"]["as built"] < 0.01


def test_skipping_the_check_with_a_swapped_waveplate_is_refused(tmp_path, capsys):
    """Item 1 (rig): without the check, free space still shows one swapped waveplate but not which: calibrate
    --skip-handedness refuses instead of writing optics it cannot pin down."""
    output = tmp_path / "calibration.json"
    path = rig_file(tmp_path, {"qwp2_swapped": True})
    assert main(["calibrate", str(path), "-o", str(output), "--yes", "--skip-handedness"]) == 2
    assert "fast and slow axes swapped" in capsys.readouterr().err and not output.exists()


def test_the_dry_run_says_whether_the_handedness_is_verified(tmp_path):
    """Item 1 (rig): the dry run tells before a long capture that acquire will refuse the calibration."""
    lines = []
    dry_run(load(rig_file(tmp_path)), out=lines.append)
    assert any(line.startswith("handedness: unverified (the rig file names no calibration)") for line in lines)


@pytest.mark.parametrize("table, value, message", [
    ("camera.optics", {"mirrored": "yes"}, r"\[camera.optics\]: mirrored must be true or false"),
    ("handedness", {"specimen": "disk"}, r"\[handedness\] has unknown key.*'specimen'"),
    ("handedness", {"defines": 3}, r"\[handedness.defines\] must be a table"),
])
def test_bad_handedness_keys_in_the_rig_file_are_refused(tmp_path, table, value, message):
    """Item 1 (rig): the new rig-file keys are checked like the others."""
    path = rig_file(tmp_path)
    text = path.read_text().replace(f"[{table}]\n", f"[{table}]\n" + "".join(
        f"{key} = {_toml(v)}\n" for key, v in value.items()))
    path.write_text(text)
    with pytest.raises(RigConfigError, match=message):
        load(path)


def test_a_rig_file_turns_the_known_specimen(tmp_path):
    """Item 1 (rig): without a scene, [handedness] defines override the default disk's values; with a scene, they
    are that scene's alone."""
    assert load(rig_file(tmp_path, handedness={"defines": {"load": 300}})).handedness.defines == {
        "load": 300, "contact_width": 4.0, "load_direction": "-0.5, 0.8660254, 0"}
    assert load(rig_file(tmp_path, handedness={"scene": "twisted_block"})).handedness.defines == {}


def test_the_readme_calibrates_the_twin_and_acquires_with_that_calibration(tmp_path, monkeypatch, capsys):
    """The README's two lines: the shipped rig file names no calibration, so acquire takes the one just written."""
    monkeypatch.chdir(tmp_path)
    assert main(["calibrate", "rig_twin", "-o", "calibration.json", "--yes"]) == 0
    assert main(["acquire", "rig_twin", "-o", "capture", "--yes", "--quiet"]) == 2
    assert "the rig file names no calibration" in capsys.readouterr().err
    assert main(["acquire", "rig_twin", "--calibration", "nowhere.json", "-o", "capture", "--yes", "--quiet"]) == 2
    assert "calibration file not found: nowhere.json" in capsys.readouterr().err
    assert not (tmp_path / "capture").exists()
    assert main(["acquire", "rig_twin", "--calibration", "calibration.json", "-o", "capture", "--yes",
                 "--quiet"]) == 0
    index = json.loads((tmp_path / "capture" / "dataset.json").read_text())
    assert index["complete"] and index["handedness"]["verified"] is True
