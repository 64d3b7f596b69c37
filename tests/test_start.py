"""A run that starts from a known field (``start=``, ``mi-nest reconstruct --start``): where it begins, what it
records, and the one-line refusals."""
import json

import numpy as np
import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.fields.base import sample
from mi_nest.io.grid import StressGrid, grid_nodes, save_stress_grid
from mi_nest.reconstruct import optimize
from mi_nest.reconstruct.config import STARTED_LEARNING_RATE, Optimiser
from mi_nest.reconstruct.fields import grid_shape
from mi_nest.reconstruct.start import SCALE_STEP
from mi_nest.scene import specimen_bounds, specimen_shapes
from scenes import tiny_disk

LOAD = 200
# One step of a rate far below the field's scale: the result is where the run started.
STAY = dict(iterations=1, learning_rate=1e-6, final_learning_rate=1e-6, batch_size=64, views_per_batch=3,
            resolution=6, kind="grid", evaluate_views=1, pixel_samples=1, average_last=0.0, start_scale_range=0.0)


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    return tiny_disk(tmp_path_factory.mktemp("data") / "disk", LOAD)


def _scene():
    return mi_nest.load_scene("disk_compression", res=8, load=LOAD)


def _truth_grid(path, shift=(0.0, 0.0, 0.0), scale=1.0, counts=(48, 48, 8), scene=None):
    """The scene's true field sampled on a grid file over the specimen's box (moved by ``shift`` mm): what an FEM
    model of the part would give."""
    scene = scene or _scene()
    low, high = specimen_bounds(specimen_shapes(scene))
    points = grid_nodes(low, high, counts)
    stress = scale * sample(scene.shapes()[0].interior_medium().field, points)
    save_stress_grid(path, StressGrid(stress.reshape(*counts[::-1], 6).astype(np.float32), low + shift,
                                      high + shift))
    return path


def test_a_start_from_the_truth_begins_at_the_best_grid_of_its_size(tiny_dataset, tmp_path):
    start = _truth_grid(tmp_path / "fem.npz")
    with pytest.warns(RuntimeWarning):
        started = optimize(_scene(), tiny_dataset, progress=False, start=str(start), **STAY)
        from_zero = optimize(_scene(), tiny_dataset, progress=False, **STAY)
    floor = started.metrics["grid_floor"]
    # The start is fitted by least squares on the final grid: it scores the best any such grid can, up to the
    # file's own sampling of the truth; from zero one step leaves the field at zero (100%).
    assert started.metrics["deviatoric_error"] < floor + 0.03
    assert from_zero.metrics["deviatoric_error"] > 0.95
    # One stage, no path curriculum: the start has chosen the branch they are there to choose.
    schedule = started.config.schedule
    assert (schedule.coarse_to_fine, schedule.path_curriculum, schedule.start) == (False, 0.0, str(start.resolve()))
    low, high = specimen_bounds(specimen_shapes(_scene()))
    assert started.field.shape == grid_shape(STAY["resolution"], high - low)
    assert any(f"from the start field {start.resolve()}" in line for line in started.source["choices"])
    assert started.source["choices"][-1] == f"start: {start.resolve()}"


def test_a_start_scaled_from_the_truth_starts_as_far_from_it(tiny_dataset, tmp_path):
    start = _truth_grid(tmp_path / "fem.npz", scale=0.8)
    with pytest.warns(RuntimeWarning):
        result = optimize(_scene(), tiny_dataset, progress=False, start=str(start), **STAY)
    # 80% of the truth is 20% off it, as near as the grid's floor lets it be.
    assert result.metrics["deviatoric_error"] == pytest.approx(0.2, abs=result.metrics["grid_floor"] + 0.03)


def test_a_start_at_the_wrong_load_is_scaled_to_the_load_the_images_prefer(tmp_path):
    data = tmp_path / "data"
    with pytest.warns(RuntimeWarning):
        simulate("disk_compression", data, SimulationSettings(azimuths=3, elevations=2, res=24, spp=4,
                                                                  test_fraction=0.2),
                 progress=False, defines={"load": LOAD, "contact_width": 4, "res": 24})
    scene = mi_nest.load_scene("disk_compression", res=24, load=LOAD, contact_width=4)
    low = _truth_grid(tmp_path / "low.npz", scale=0.8, scene=scene)
    exact = _truth_grid(tmp_path / "exact.npz", scene=scene)
    fine = {**STAY, "resolution": 24}
    with pytest.warns(RuntimeWarning):
        scaled = optimize(scene, data, progress=False, start=str(low), **{**fine, "start_scale_range": 0.4})
        as_given = optimize(scene, data, progress=False, start=str(low), **fine)
        from_exact = optimize(scene, data, progress=False, start=str(exact), **fine)
    # The model at 80% of the load is taken at 1.25 times it, within a step of the scan, and starts where the exact
    # model does (the file's own sampling of the truth sets how near that is).
    factor = scaled.history[0]["start_factor"]
    assert abs(factor - 1.25) <= SCALE_STEP
    assert scaled.metrics["deviatoric_error"] < from_exact.metrics["deviatoric_error"] + 0.01
    assert as_given.metrics["deviatoric_error"] > from_exact.metrics["deviatoric_error"] + 0.05
    assert f"at {factor:.2f} times its load" in scaled.source["choices"][-1]
    assert as_given.history[0]["start_factor"] == 1.0
    # A load series: the field at a quarter of the load, taken at the ratio of the loads and scanned about it.
    quarter = _truth_grid(tmp_path / "quarter.npz", scale=0.25, scene=scene)
    with pytest.warns(RuntimeWarning):
        series = optimize(scene, data, progress=False, start=str(quarter),
                          **{**fine, "start_load_ratio": 4.0, "start_scale_range": 0.1})
        unscaled = optimize(scene, data, progress=False, start=str(quarter), **{**fine, "start_scale_range": 0.1})
    assert abs(series.history[0]["start_factor"] - 4.0) <= 4.0 * SCALE_STEP
    assert series.metrics["deviatoric_error"] < from_exact.metrics["deviatoric_error"] + 0.01
    assert unscaled.metrics["deviatoric_error"] > 0.6
    assert "the factor from 3.60 to 4.40" in series.source["choices"][-1]


def test_a_reconstruction_is_a_start(tiny_dataset, tmp_path):
    with pytest.warns(RuntimeWarning):
        first = optimize(_scene(), tiny_dataset, output=tmp_path / "first", progress=False,
                         start=str(_truth_grid(tmp_path / "fem.npz")), **STAY)
        again = optimize(_scene(), tiny_dataset, progress=False, start=str(tmp_path / "first"), **STAY)
    # The same grid fitted to itself gives itself back.
    assert np.abs(again.field.nodes() - first.field.nodes()).max() < 1e-3 * np.abs(first.field.nodes()).max()


@pytest.mark.parametrize("case, message", [
    ("missing", "start field not found"),
    ("directory", "without a reconstruction's field.npz"),
    ("suffix", "not a stress file"),
    ("elsewhere", r"covers 0% of the specimen .* another part or other coordinates"),
    ("zero", "holds no stress inside the specimen"),
])
def test_a_start_that_cannot_serve_is_refused_in_one_line(tiny_dataset, tmp_path, case, message):
    path = {"missing": lambda: tmp_path / "none.TSV",
            "directory": lambda: tmp_path,
            "suffix": lambda: _write(tmp_path / "field.txt"),
            "elsewhere": lambda: _truth_grid(tmp_path / "moved.npz", shift=(100.0, 0.0, 0.0)),
            "zero": lambda: _truth_grid(tmp_path / "zero.npz", scale=0.0)}[case]()
    with pytest.warns(RuntimeWarning), pytest.raises(ValueError, match=message) as error:
        optimize(_scene(), tiny_dataset, progress=False, start=str(path), **STAY)
    assert "\n" not in str(error.value)


def test_a_start_is_refused_for_networks_and_beside_a_warm_start(tiny_dataset, tmp_path):
    start = str(_truth_grid(tmp_path / "fem.npz"))
    with pytest.raises(ValueError, match="fitted by grids only"):
        optimize(_scene(), tiny_dataset, progress=False, start=start, kind="mlp")
    with pytest.raises(ValueError, match="give one"):
        optimize(_scene(), tiny_dataset, progress=False, start=start, warm_start=0.2)
    with pytest.raises(ValueError, match=r"'start_scale_range' is a share of the start's load in \[0, 1\)"):
        optimize(_scene(), tiny_dataset, progress=False, start=start, start_scale_range=1.5)
    for ratio in (0.0, -2.0, float("nan")):
        with pytest.raises(ValueError, match="'start_load_ratio' must be the test's load over the start's"):
            optimize(_scene(), tiny_dataset, progress=False, start=start, start_load_ratio=ratio)
    with pytest.raises(ValueError, match="no start is given"):
        optimize(_scene(), tiny_dataset, progress=False, start_load_ratio=3.0)


def test_cli_starts_from_a_field_and_says_so(tiny_dataset, tmp_path, capsys):
    start = _truth_grid(tmp_path / "fem.npz")
    arguments = ["reconstruct", str(tiny_dataset), "--allow-aliased", "--iterations", "1", "--resolution", "6",
                 "--kind", "grid", "--option", "batch_size=64", "--no-progress"]
    assert main(arguments + ["-o", str(tmp_path / "run"), "--start", str(start)]) == 0
    saved = json.loads((tmp_path / "run" / "reconstruction.json").read_text())
    assert saved["config"]["schedule"]["start"] == str(start.resolve())
    assert saved["source"]["choices"][-1].startswith(f"start: {start.resolve()} at ")
    # A started run steps at a tenth of the descent's rate, and says so; a rate given is the user's, even the
    # descent's own.
    assert saved["config"]["optimiser"]["learning_rate"] == STARTED_LEARNING_RATE == Optimiser().learning_rate / 10
    assert "learning rate 0.005 (a started run's, below the descent's" in saved["source"]["choices"][1]
    given = ["--option", f"learning_rate={Optimiser().learning_rate}"]
    assert main(arguments + ["-o", str(tmp_path / "given"), "--start", str(start), *given]) == 0
    saved = json.loads((tmp_path / "given" / "reconstruction.json").read_text())
    assert saved["config"]["optimiser"]["learning_rate"] == Optimiser().learning_rate
    assert saved["source"]["choices"][1].endswith("learning rate 0.05")
    capsys.readouterr()
    assert main(arguments + ["-o", str(tmp_path / "bad"), "--start", str(tmp_path / "none.TSV")]) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0


def _write(path):
    path.write_text("not a field\n")
    return path
