"""One truth: a reconstruction, its metrics and its views are scored against the field its dataset was
simulated from, whatever scene they are given; a scene that differs is named value by value."""
import json
import shutil
import warnings

import numpy as np
import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.dataset import simulate
from mi_nest.dataset.truth import SceneRecord, recorded_scene, recorded_truth
from mi_nest.fields.base import sample
from mi_nest.views import open_source
from mi_nest.reconstruct import optimize
from mi_nest.scene import SceneError, specimen_media
from scenes import TINY

FAST = dict(iterations=3, batch_size=64, views_per_batch=3, learning_rate=0.1, resolution=6, evaluate_views=1,
            pixel_samples=1, seed=4)
DEFINES = {"load": 60, "contact_width": 4}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    directory = tmp_path_factory.mktemp("truth") / "disk"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # 8 px: the contacts' fringes alias
        simulate("disk_compression", directory, TINY, progress=False, defines=DEFINES)
    return directory


def _optimize(scene, dataset, **options):
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", ".*denser than the pixels", RuntimeWarning)
        return optimize(scene, dataset, progress=False, kind="grid", **FAST, **options)


def _field_values(scene):
    points = np.array([[0.0, 0.0, 0.0], [5.0, 3.0, 1.0], [-8.0, 10.0, -2.0]])
    return sample(specimen_media(scene)[0].field, points)


def test_a_scene_with_the_default_load_is_scored_against_the_dataset_s_field_and_named(dataset):
    right = _optimize(mi_nest.load_scene("disk_compression", res=8, **DEFINES), dataset)
    with pytest.warns(RuntimeWarning, match=r"contact_width 0 vs 4; load 1000 vs 60: given vs recorded"):
        wrong = _optimize(mi_nest.load_scene("disk_compression", res=8), dataset)
    # The field does not enter the fit (same seed: same field), so the same truth gives the same error.
    assert wrong.metrics["deviatoric_error"] == pytest.approx(right.metrics["deviatoric_error"], rel=1e-6)
    against_default = _optimize(mi_nest.load_scene("disk_compression", res=8), dataset,
                                truth=specimen_media(mi_nest.load_scene("disk_compression", res=8))[0].field)
    # ... which is not what the scene's own (default) field gives: a silent wrong truth would fail above.
    assert against_default.metrics["deviatoric_error"] != pytest.approx(right.metrics["deviatoric_error"], rel=1e-3)


def test_a_scene_name_is_loaded_with_the_dataset_s_defines_without_a_warning(dataset):
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        warnings.filterwarnings("ignore", ".*denser than the pixels", RuntimeWarning)
        result = optimize("disk_compression", dataset, progress=False, kind="grid", **FAST)
    assert result.source["defines"]["load"] == "60"


def test_a_scene_whose_specimen_lies_elsewhere_is_refused_naming_both(dataset):
    with pytest.raises(SceneError, match=r"holds its specimens from \(-15, -15, -3\) to \(15, 15, 3\) mm, the one .* "
                                         r"from \(-20, -20, -3\) to \(20, 20, 3\) mm"):
        _optimize(mi_nest.load_scene("disk_compression", res=8, diameter=30, **DEFINES), dataset)


def test_the_recorded_truth_is_the_field_the_dataset_was_simulated_from(dataset, tmp_path):
    scene, truth = recorded_truth(mi_nest.Dataset(dataset))
    points = np.array([[0.0, 0.0, 0.0], [5.0, 3.0, 1.0], [-8.0, 10.0, -2.0]])
    np.testing.assert_array_equal(sample(truth, points),
                                  _field_values(mi_nest.load_scene("disk_compression", res=8, **DEFINES)))
    assert not np.allclose(sample(truth, points), _field_values(mi_nest.load_scene("disk_compression", res=8)))
    assert specimen_media(scene)[0].field is not None
    capture = tmp_path / "capture"
    shutil.copytree(dataset, capture)
    index = json.loads((capture / "dataset.json").read_text())
    index["source"] = {"kind": "captured"}
    (capture / "dataset.json").write_text(json.dumps(index))
    with pytest.raises(SceneError, match="records no simulated scene"):
        recorded_truth(mi_nest.Dataset(capture))


def test_records_compare_values_not_spellings_and_skip_the_sampling(dataset):
    record = recorded_scene(mi_nest.Dataset(dataset).index["source"])
    same = SceneRecord(record.file, {"load": "60.0", "contact_width": "4", "res": "256", "spp": "64"})
    assert same.differences(record) == []
    assert SceneRecord(record.file, {"load": "61"}).differences(record) == ["contact_width 0 vs 4", "load 61 vs 60"]


def test_views_of_a_reconstruction_with_another_scene_show_the_dataset_s_truth(dataset, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        optimize(mi_nest.load_scene("disk_compression", res=8), dataset, output=tmp_path / "result",
                 progress=False, kind="grid", **FAST)
    source = open_source(tmp_path / "result")
    with pytest.warns(RuntimeWarning, match="load 1000 vs 60"):
        truth = source.truth()
    expected = _field_values(mi_nest.load_scene("disk_compression", res=8, **DEFINES))
    np.testing.assert_allclose(_field_values(truth.scene), expected, rtol=1e-6)


def test_compare_reports_the_psnr_reconstruct_reports(dataset, tmp_path, capsys):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        result = optimize("disk_compression", dataset, output=tmp_path / "result", progress=False, kind="grid",
                          **{**FAST, "evaluate_views": 4})
        assert main(["compare", str(tmp_path / "result"), "-o", str(tmp_path / "compare.png")]) == 0
    printed = capsys.readouterr().out
    mean = float(printed.split("mean ")[1].split(" dB")[0])
    # compare renders with the scene's samples per pixel, reconstruct at pixel centres: close, not equal.
    assert mean == pytest.approx(result.metrics["test_psnr"], abs=1.0)
