"""Multi-axis polariscope datasets: schedule, camera model, masks, format, resume, loader, CLI."""
import json
import warnings

import mi_nest
import numpy as np
import pytest

from mi_nest.cli import main
from mi_nest.dataset import CameraModel, Dataset, DatasetError, SimulationSettings, simulate
from mi_nest.dataset.camera import MOSAIC, mosaic_mask
from mi_nest.dataset.format import rotation_header
from mi_nest.dataset.masks import agreement, linear_settings, min_dolp
from mi_nest.dataset.schedule import Rotation, angles, camera_to_world, rotation_grid
from mi_nest.dataset.simulate import WRITE_QUEUE, WRITERS
from mi_nest.io.exr import write_channels
from mi_nest.physics import MEASUREMENTS, su2
from mi_nest.physics.aliasing import ALIASED_FRACTION, NYQUIST
from mi_nest.scene import pose, reference_pose

SMALL = SimulationSettings(azimuths=4, elevations=4, res=32, spp=1)


@pytest.fixture(scope="module")
def disk_dataset(tmp_path_factory):
    directory = tmp_path_factory.mktemp("data") / "disk"
    with pytest.warns(RuntimeWarning, match="denser than the pixel grid"):
        report = simulate("disk_compression", directory, SMALL, progress=False)
    return directory, report


def test_grid_follows_the_paper_and_holds_out_a_seeded_fifth():
    rotations = rotation_grid(32, 32, 180.0, 180.0)
    assert len(rotations) == 1024 and sum(r.split == "test" for r in rotations) == 205
    assert angles(4, 180.0) == [-67.5, -22.5, 22.5, 67.5]
    assert [r.split for r in rotation_grid(5, 5, 90, 90, seed=3)] == [r.split for r in rotation_grid(5, 5, 90, 90, seed=3)]
    with pytest.raises(ValueError):
        rotation_grid(0, 4, 180, 180)


def test_turning_the_specimen_moves_the_camera_the_other_way_about_its_centre():
    reference = np.eye(4)
    reference[:3, 3] = [1.0, 2.0, 103.0]          # camera at +z of the centre, looking down -z
    center = np.array([1.0, 2.0, 3.0])
    moved = camera_to_world(reference, Rotation(0, 90.0, 0.0, "train"), center)
    # The specimen turned +90 about up (y) is seen from -x: the camera sits at centre - 100 x.
    np.testing.assert_allclose(moved[:3, 3], center + [-100.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(moved[:3, :3] @ moved[:3, :3].T, np.eye(3), atol=1e-12)
    tipped = camera_to_world(reference, Rotation(0, 0.0, 90.0, "train"), center)
    np.testing.assert_allclose(tipped[:3, 3], center + [0.0, 100.0, 0.0], atol=1e-9)


def test_rotations_see_the_box_along_its_other_axes():
    from scenes import box, medium, scene
    loaded = scene([box((10, 20, 40), interior=medium(xx=1.0))], res=3, view=30.0)
    reference = np.array(reference_pose(loaded))
    lengths = []
    for azimuth, elevation in ((0, 0), (90, 0), (0, 90)):
        pose(loaded, camera_to_world(reference, Rotation(0, azimuth, elevation, "train"), np.zeros(3)))
        lengths.append(float(mi_nest.render(loaded).channels["path.length"][1, 1]))
    np.testing.assert_allclose(lengths, [40.0, 10.0, 20.0], rtol=1e-5)


def test_camera_model_noise_statistics_quantisation_and_seeds():
    flat = {name: np.full((200, 200), 0.5) for name in MEASUREMENTS}
    noisy = CameraModel(read_noise=0.01, seed=1).capture(flat, 7)
    values = np.stack(list(noisy.values()))
    assert abs(values.std() - 0.01) < 5e-4 and abs(values.mean() - 0.5) < 5e-4
    again = CameraModel(read_noise=0.01, seed=1).capture(flat, 7)
    assert all(np.array_equal(noisy[n], again[n]) for n in flat)
    assert not np.array_equal(noisy["pol.45.0.0"], CameraModel(read_noise=0.01, seed=1).capture(flat, 8)["pol.45.0.0"])
    shot = np.stack(list(CameraModel(full_well=1000.0).capture(flat, 0).values()))
    assert shot.var() == pytest.approx(0.5 / 1000.0, rel=0.05)
    bright = {name: np.full((4, 4), 1.7) for name in MEASUREMENTS}
    assert all(np.all(v == 1.0) for v in CameraModel(bits=8).capture(bright, 0).values())
    ramp = {name: np.linspace(0, 1, 64).reshape(8, 8) for name in MEASUREMENTS}
    quantised = CameraModel(bits=8).capture(ramp, 0)["pol.45.0.0"]
    np.testing.assert_allclose(quantised * 255, np.round(quantised * 255), atol=1e-4)
    with pytest.raises(ValueError):
        CameraModel(bits=7)


def test_mosaic_is_the_imx250mzr_cell_and_bilinear_demosaicking_keeps_smooth_images():
    assert MOSAIC == ((90, 45), (135, 0))
    assert mosaic_mask(90, (4, 4))[0, 0] and mosaic_mask(45, (4, 4))[0, 1] and mosaic_mask(0, (4, 4))[1, 1]
    y, x = np.mgrid[:32, :32]
    plane = {name: 0.2 + 0.01 * x + 0.005 * y for name in MEASUREMENTS}
    demosaicked = CameraModel(mosaic=True).capture(plane, 0)
    for name in MEASUREMENTS:      # bilinear interpolation is exact on a plane, away from the border
        np.testing.assert_allclose(demosaicked[name][2:-2, 2:-2], plane[name][2:-2, 2:-2], atol=1e-6)


def test_free_space_shows_full_linear_polarisation_in_the_linear_settings():
    assert linear_settings() == [(45, 0), (45, 45), (90, 0)]
    identity = su2.identity(np.zeros((2, 2)))
    free = {name: scope.intensity(identity) for name, scope in MEASUREMENTS.items()}
    np.testing.assert_allclose(min_dolp(free), 1.0, atol=1e-12)
    slab = su2.retarder(np.full((2, 2), 1.0), np.full((2, 2), 0.3))
    assert np.all(min_dolp({name: scope.intensity(slab) for name, scope in MEASUREMENTS.items()}) < 0.9)


def test_round_trip_rerenders_a_rotation_exactly(disk_dataset):
    directory, report = disk_dataset
    assert report.rendered == 16 and report.kept == 0
    dataset = Dataset(directory)
    assert len(dataset) == 16 and len(dataset.split("test")) == 3 and dataset.resolution == (32, 32)
    index = json.loads((directory / "dataset.json").read_text())
    assert index["complete"] and index["wavelength"] == [532.0] and index["units"]["length"] == "mm"
    assert index["software"]["mi_nest"] == mi_nest.__version__
    scene = mi_nest.load_scene("disk_compression", res=32)
    position = 5
    pose(scene, dataset.to_world(position))
    rendered = mi_nest.render(scene, spp=1).channels
    stored = dataset.view(position)
    for name in MEASUREMENTS:      # stored as half floats: equal after the same rounding
        assert np.array_equal(stored[name], rendered[name].astype(np.float16).astype(np.float32)), name
    np.testing.assert_array_equal(dataset.view(position, ["mask.occupancy"])["mask.occupancy"],
                                  rendered["path.length"] > 0)


def test_dolp_mask_agrees_with_the_exact_occupancy(disk_dataset):
    directory, report = disk_dataset
    assert report.mask_iou > 0.85
    view = Dataset(directory).view(0, ["mask.dolp", "mask.occupancy"])
    assert agreement(view["mask.dolp"] > 0.5, view["mask.occupancy"] > 0.5).recall > 0.9


def test_the_index_counts_the_views_whose_fringes_alias(disk_dataset, tmp_path):
    summary = Dataset(disk_dataset[0]).index["fringe_aliasing"]
    # The shipped disk's point loads are singular: dense fringes at the contacts in every view.
    assert summary["of"] == 16 and summary["views"] == 16 and summary["densest"] > NYQUIST
    assert ALIASED_FRACTION < summary["mean_fraction"] <= summary["max_fraction"] < 1
    # Forty times less load over wide contacts: every fringe resolved, in every view.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        simulate("disk_compression", tmp_path / "soft", SimulationSettings(azimuths=2, elevations=2, res=32, spp=1),
                 defines={"load": 25, "contact_width": 8}, progress=False)
    summary = Dataset(tmp_path / "soft").index["fringe_aliasing"]
    assert summary["views"] == 0 and summary["of"] == 4 and 0 < summary["densest"] < NYQUIST


def test_an_interrupted_simulation_resumes_to_an_identical_dataset(tmp_path, disk_dataset):
    settings = SimulationSettings(azimuths=4, elevations=4, res=32, spp=1, camera=CameraModel(read_noise=0.01, bits=12))
    whole = tmp_path / "whole"
    simulate("disk_compression", whole, settings, progress=False)

    class Killed(Exception):
        pass

    def kill_after_five(entry):
        if entry["index"] == 5:
            raise Killed
    resumed = tmp_path / "resumed"
    with pytest.raises(Killed):
        simulate("disk_compression", resumed, settings, progress=False, on_rotation=kill_after_five)
    with pytest.raises(DatasetError, match="incomplete"):
        Dataset(resumed)
    # Rotations 0 to 5 are on disk, and the ones rendered while the writers wrote them are written too: an
    # interrupted run keeps all it rendered. The run learns that rotation 5 is on disk after its next render, so
    # up to the queue and one rotation per writer thread follow it (12 seen once on a busy machine).
    on_disk = len(Dataset(resumed, allow_incomplete=True))
    assert 6 <= on_disk <= 6 + WRITE_QUEUE + WRITERS
    report = simulate("disk_compression", resumed, settings, progress=False)
    assert (report.rendered, report.kept) == (16 - on_disk, on_disk)
    a, b = Dataset(whole), Dataset(resumed)
    for position in range(16):
        assert all(np.array_equal(a.view(position)[n], b.view(position)[n]) for n in MEASUREMENTS)
    assert json.loads((whole / "dataset.json").read_text()) == json.loads((resumed / "dataset.json").read_text())


def test_ray_batches_come_from_inside_the_mask_of_the_training_rotations(disk_dataset):
    dataset = Dataset(disk_dataset[0])
    positions, rows, columns, targets = dataset.ray_batch(500, np.random.default_rng(0))
    assert targets.shape == (500, 16) and set(positions) <= set(dataset.split("train"))
    for p, r, c, t in zip(positions[:20], rows[:20], columns[:20], targets[:20]):
        assert dataset.view(p, ["mask.dolp"])["mask.dolp"][r, c] == 1.0
        np.testing.assert_array_equal(t, dataset.measurements(p)[r, c])


def _bytes_held(view):
    """Counted from the arrays a cached view holds (each once: the measurements' images are slices of their
    stack), not from its own ``nbytes``."""
    others = [a for a in view.images.values() if not np.shares_memory(a, view.measured)]
    return sum(a.nbytes for a in (*others, view.measured, *view.mask_pixels.values()))


def test_a_cached_view_holds_its_measurements_once(disk_dataset):
    dataset = Dataset(disk_dataset[0])
    view = dataset._decoded(0)
    view.pixels_inside("mask.dolp")
    assert view.nbytes == _bytes_held(view)
    masks = len(view.images) - len(dataset.channels)
    assert view.nbytes < view.measured.nbytes * (1 + (masks + 1) / len(dataset.channels))
    images = dataset.view(0)
    for i, name in enumerate(dataset.channels):
        np.testing.assert_array_equal(images[name], dataset.measurements(0)[..., i])


def test_the_cache_takes_half_the_free_memory_and_at_least_a_gibibyte(disk_dataset, monkeypatch):
    import types

    import psutil

    from mi_nest.dataset.loader import MIN_CACHE_BYTES
    for free, budget in ((64 << 30, 32 << 30), (1 << 29, MIN_CACHE_BYTES)):
        monkeypatch.setattr(psutil, "virtual_memory", lambda free=free: types.SimpleNamespace(available=free))
        assert Dataset(disk_dataset[0])._cache_bytes == budget
    assert Dataset(disk_dataset[0], cache_bytes=12345)._cache_bytes == 12345


@pytest.mark.parametrize("views_held", [None, 3])
def test_views_are_decoded_once_while_the_cache_holds_them(disk_dataset, monkeypatch, views_held):
    from mi_nest.dataset import format as dataset_format     # where rotation files are read
    decoded = []
    read = dataset_format.read_channels
    monkeypatch.setattr(dataset_format, "read_channels", lambda path: decoded.append(path) or read(path))
    dataset = Dataset(disk_dataset[0])
    if views_held is not None:
        for p in dataset.split("train"):
            dataset._decoded(p).pixels_inside("mask.dolp")          # counted too: a view holding them is larger
        largest = max(map(_bytes_held, map(dataset._decoded, dataset.split("train"))))
        dataset = Dataset(disk_dataset[0], cache_bytes=views_held * largest)
        decoded.clear()
    rng = np.random.default_rng(0)
    for _ in range(20):
        dataset.ray_batch(100, rng, views_per_batch=4)
    train = len(dataset.split("train"))
    assert len(dataset._cache) == (train if views_held is None else views_held)
    assert sum(map(_bytes_held, dataset._cache.values())) <= dataset._cache_bytes
    if views_held is None:
        assert sorted(decoded) == sorted(set(decoded)) and len(decoded) == train      # each file once
    else:
        assert len(decoded) > train      # evicted views are decoded again
    with pytest.raises(ValueError, match="read-only"):
        dataset.measurements(dataset.split("train")[0])[0, 0, 0] = 1.0


def test_bad_input_is_reported_clearly(tmp_path, disk_dataset):
    directory = disk_dataset[0]
    with pytest.raises(ValueError, match="unknown channel"):
        Dataset(directory).view(0, ["pol.45.0.30"])
    with pytest.raises(DatasetError, match="not found"):
        Dataset(tmp_path / "nowhere")
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "dataset.json").write_text("{ not json")
    with pytest.raises(DatasetError, match="corrupt"):
        Dataset(broken)
    import shutil
    copy = tmp_path / "copy"
    shutil.copytree(directory, copy)
    (copy / "rotations/0003.exr").unlink()
    with pytest.raises(DatasetError, match="missing.*0003.exr"):
        Dataset(copy)
    index = json.loads((copy / "dataset.json").read_text())
    write_channels(copy / "rotations/0003.exr", {n: np.zeros((16, 16)) for n in MEASUREMENTS},
                   metadata=rotation_header(index["rotations"][3], index))    # rotation 3's, at another size
    with pytest.raises(DatasetError, match="16, 16"):
        Dataset(copy).view(3)
    with pytest.raises(DatasetError, match="other settings"):
        simulate("disk_compression", copy, SimulationSettings(azimuths=2, elevations=2, res=32, spp=1), progress=False)


def test_cli_simulates_and_shows_a_contact_sheet(tmp_path, capsys):
    out = tmp_path / "cli"
    assert main(["simulate", "twisted_block", "-o", str(out), "--azimuth", "2", "--elevation", "2", "--res", "8",
                 "--spp", "1", "--noise", "0.01", "--mosaic"]) == 0
    assert "4 rotations rendered" in capsys.readouterr().out
    assert main(["show", str(out), "-c", "pol.90.45.135"]) == 0
    assert (out / "contact_sheet.png").stat().st_size > 1000
    assert main(["show", str(out), "-c", "nope"]) == 2
    assert "unknown channel" in capsys.readouterr().err


def test_a_writer_error_stops_the_simulation_with_that_error(tmp_path, monkeypatch):
    import importlib
    simulation = importlib.import_module("mi_nest.dataset.simulate")
    calls = []

    def failing(path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 3:
            raise OSError(f"{path}: No space left on device")
        return original(path, *args, **kwargs)
    original = simulation.write_rotation
    monkeypatch.setattr(simulation, "write_rotation", failing)
    settings = SimulationSettings(azimuths=4, elevations=4, res=16, spp=1)
    with pytest.raises(OSError, match="No space left on device"):
        simulate("disk_compression", tmp_path / "data", settings, progress=False)
    # The run stopped at the failure: only what the writers had in hand beside it was written.
    written = len(Dataset(tmp_path / "data", allow_incomplete=True))
    assert 2 <= written <= 2 + WRITE_QUEUE + 1
    monkeypatch.setattr(simulation, "write_rotation", original)
    report = simulate("disk_compression", tmp_path / "data", settings, progress=False)
    assert (report.kept, report.rendered) == (written, 16 - written)
