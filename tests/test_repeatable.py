"""A seeded reconstruction repeats: bit for bit with ``deterministic=True`` (one thread), and a time budget is
refused with it, since the clock decides where such a run ends."""
import drjit as dr
import numpy as np
import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.reconstruct import optimize


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    directory = tmp_path_factory.mktemp("repeat") / "disk"
    settings = SimulationSettings(azimuths=3, elevations=3, res=16, spp=1, test_fraction=0.2)
    simulate("disk_compression", directory, settings, progress=False, defines={"load": 30})
    return directory


def test_a_deterministic_run_repeats_bit_for_bit_and_gives_its_threads_back(dataset):
    threads = dr.thread_count()
    scene = mi_nest.load_scene("disk_compression", res=16, load=30)
    runs = [optimize(scene, dataset, progress=False, iterations=150, batch_size=1024, resolution=12,
                     evaluate_views=1, seed=3, deterministic=True) for _ in range(2)]
    first, second = (np.array(run.field.texture.tensor()) for run in runs)
    assert np.abs(first).max() > 0.1          # the field moved: the comparison is not of two zero grids
    np.testing.assert_array_equal(first, second)
    assert runs[0].metrics["deviatoric_error"] == runs[1].metrics["deviatoric_error"]
    assert [h["loss"] for h in runs[0].history] == [h["loss"] for h in runs[1].history]
    assert dr.thread_count() == threads


def test_a_deterministic_run_with_a_time_budget_is_refused_in_one_line(dataset, tmp_path, capsys):
    with pytest.raises(ValueError, match="a deterministic run repeats a fixed number of iterations"):
        optimize(mi_nest.load_scene("disk_compression", res=16, load=30), dataset, progress=False,
                 deterministic=True, time_limit=60.0)
    assert main(["reconstruct", str(dataset), "-o", str(tmp_path / "out"), "--deterministic", "--minutes", "1",
                 "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "drop the time limit (--minutes) or deterministic" in error
    assert not (tmp_path / "out").exists()
