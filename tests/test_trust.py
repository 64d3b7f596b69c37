"""Where to trust a reconstruction: the trust map's terms against what they must be."""
import json

import numpy as np
import pytest

import mi_nest
from mi_nest.dataset import Dataset, SimulationSettings, simulate
from mi_nest.reconstruct import Reconstruction, optimize
from mi_nest.reconstruct.evaluation import heldout_predictions
from mi_nest.reconstruct.trust import TRUST_FILE, TrustMap, imbalance, trust_map
from mi_nest.fields.base import sample
from mi_nest.physics.tensors import deviatoric_part, tensor_norm
from scenes import disk_deviator_grid


def test_a_balanced_field_is_trusted_more_than_a_planted_imbalance():
    scene = mi_nest.load_scene("disk_compression", res=8, load=100, contact_width=4)
    # Planted: the truth scaled by a factor that grows along x.
    grids = (disk_deviator_grid()[0],
             disk_deviator_grid(lambda truth, nodes: truth * (1.0 + (nodes[:, :1] + 20.0) / 40.0))[0])
    exact, planted = (imbalance(scene, grid, grid.shape) for grid in grids)
    centre = np.s_[:, 8:24, 8:24]      # away from the contacts, where the grid resolves the truth
    assert np.nanmedian(exact[centre]) < np.nanmedian(planted[centre]) / 3
    assert np.isnan(exact[:, 0, 0]).all()       # the box's corners lie outside the disk


@pytest.fixture(scope="module")
def one_axis_and_two_axes(tmp_path_factory):
    root = tmp_path_factory.mktemp("trust")
    data = {}
    for name, elevations in (("one", 1), ("two", 3)):
        settings = SimulationSettings(azimuths=6, elevations=elevations, res=16, spp=1, test_fraction=0.2)
        simulate("disk_compression", root / name, settings, progress=False, defines={"load": 20})
        data[name] = root / name
    return data


def test_rays_from_one_rotation_axis_span_a_plane_and_two_axes_do_not(one_axis_and_two_axes):
    spreads = {}
    for name, directory in one_axis_and_two_axes.items():
        dataset = Dataset(directory)
        scene = mi_nest.load_scene("disk_compression", res=16, load=20)
        result = optimize(scene, dataset, progress=False, iterations=2, batch_size=64, resolution=8,
                          evaluate_views=1)
        predictions = heldout_predictions(scene, dataset, result.field, result.tracer(scene), 1)
        trust = trust_map(scene, dataset, result.field, predictions)
        seen = trust.coverage > 0
        assert 0 <= trust.coverage.min() and trust.coverage.max() <= 1
        spreads[name] = float(np.median(trust.direction_spread[seen]))
    assert spreads["one"] < 1e-3       # every ray lies in the plane normal to the rotation axis
    assert spreads["two"] > 0.05


def test_a_run_writes_its_trust_map_and_summary(one_axis_and_two_axes, tmp_path):
    directory = one_axis_and_two_axes["two"]
    scene = mi_nest.load_scene("disk_compression", res=16, load=20)
    result = optimize(scene, directory, output=tmp_path / "out", progress=False, iterations=2, batch_size=64,
                      resolution=8, evaluate_views=1)
    trust = TrustMap.load(tmp_path / "out" / TRUST_FILE)
    assert trust.imbalance.shape == result.field.texture.tensor().shape[:3]
    summary = json.loads((tmp_path / "out" / "reconstruction.json").read_text())["metrics"]["trust"]
    assert summary["nodes"] == int(np.isfinite(trust.imbalance).sum()) > 0
    assert np.isfinite(summary["uncertainty_median"])
    # The curvature spread from the run's own Adam moments, on the nodes the imbalance measures.
    measured = np.isfinite(trust.imbalance)
    assert np.array_equal(np.isfinite(trust.curvature_spread), measured)
    assert np.nanmedian(trust.curvature_spread) == pytest.approx(1.0)
    described = result.describe()
    assert "equilibrium imbalance" in described and "given to mi-nest spread" in described


def test_the_trust_map_at_a_point_is_its_nearest_measured_node():
    """Export nodes on the part's surface fall nearest lattice nodes the imbalance was not measured at; they take
    the nearest measured node's value, not NaN."""
    values = np.full((2, 3, 4), np.nan)
    values[:, 1, 1] = 5.0
    values[:, 1, 2] = 7.0
    trust = TrustMap(np.zeros(3), np.array([3.0, 2.0, 1.0]), values, values, values, values, [], [])
    points = np.array([[1.0, 1.0, 0.0], [2.2, 0.9, 1.0], [0.0, 0.0, 0.0], [3.0, 2.0, 1.0]])
    np.testing.assert_array_equal(trust.at(points), [5.0, 7.0, 5.0, 7.0])
    exported = trust.point_data(points)
    assert list(exported) == ["trust_uncertainty", "trust_imbalance", "trust_coverage", "trust_direction_spread",
                              "trust_heldout_residual"]
    blank = TrustMap(np.zeros(3), np.ones(3), *(np.full((2, 2, 2), np.nan),) * 4, [], [])
    assert np.isnan(blank.at(points)).all()


def test_the_uncertainty_ranking_is_spearmans_over_the_pixels_where_both_are_known():
    from mi_nest.views.principal import uncertainty_ranking
    error = np.array([[0.1, 0.5, np.nan], [2.0, 0.3, 9.0]])
    assert uncertainty_ranking(np.log(error), error) == pytest.approx(1.0)
    assert uncertainty_ranking(-error, error) == pytest.approx(-1.0)
    # Rank differences 0, 1, 1, 2, 0 over the five known pixels: 1 - 6 * 6 / (5 * 24).
    assert uncertainty_ranking(np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]), error) == pytest.approx(0.7)
    assert np.isnan(uncertainty_ranking(np.array([[1.0, np.nan, np.nan], [2.0, np.nan, np.nan]]), error))


def test_a_run_says_what_it_chose_from_the_data_and_records_it(one_axis_and_two_axes, tmp_path, capsys):
    """Section 5 of issue 34: a run with no options prints what its defaults became on these data."""
    scene = mi_nest.load_scene("disk_compression", res=16, load=20)
    result = optimize(scene, one_axis_and_two_axes["one"], output=tmp_path / "out", progress=True, iterations=2,
                      batch_size=64, evaluate_views=1)
    printed = capsys.readouterr().out.splitlines()
    data_line, chose_line = (next(line for line in printed if line.startswith(prefix))
                             for prefix in ("data:", "chose:"))
    train = len(Dataset(one_axis_and_two_axes["one"]).split("train"))
    # One rotation axis: azimuths only, 16 x 16 pixels; the disk (40 x 40 x 6 mm) needs 64 nodes for 10 across.
    assert data_line.startswith(f"data: {train} training rotations, azimuths spanning ")
    assert "elevation" not in data_line
    assert "at 16x16 pixels" in data_line
    nx, ny, nz = result.field.shape
    assert (nx, ny, nz) == (64, 64, 11)
    assert chose_line.startswith(f"chose: grid {nx}x{ny}x{nz} (the coarsest of 32, 48, 64 nodes")
    assert "NeST-general" in chose_line and "eased above a field RMS of 1 stress scales" in chose_line
    recorded = json.loads((tmp_path / "out" / "reconstruction.json").read_text())["source"]["choices"]
    assert recorded == [data_line, chose_line]


def test_the_curvature_spread_is_the_inverse_root_of_the_mean_squared_gradient():
    from mi_nest.reconstruct.trust import curvature_spread
    second_moment = np.ones((1, 2, 3, 5))
    second_moment[0, 0, 0] = 4.0            # pulled on twice as hard: half the spread
    second_moment[0, 1, 2] = 123.0           # outside: not reported
    inside = np.ones((1, 2, 3), bool)
    inside[0, 1, 2] = False
    spread = curvature_spread(second_moment, inside)
    np.testing.assert_allclose(spread[inside], [0.5, 1.0, 1.0, 1.0, 1.0])
    assert np.isnan(spread[0, 1, 2])
    never = np.zeros((1, 1, 2, 5))
    never[0, 0, 0] = 1.0
    assert spread.dtype == np.float64 and np.isfinite(curvature_spread(never, np.ones((1, 1, 2), bool))).all()


def test_dense_fringes_choose_the_finest_grid_and_say_why(one_axis_and_two_axes):
    from mi_nest.reconstruct.choices import choices
    from mi_nest.reconstruct.config import OptimizeConfig
    from mi_nest.reconstruct.fields import settle
    dataset = Dataset(one_axis_and_two_axes["two"])
    dataset.index["fringe_aliasing"] = {"views": 9, "of": 12, "mean_fraction": 0.19, "max_fraction": 0.4,
                                        "densest": 2.5}
    box = np.array([40.0, 40.0, 12.0])          # the stacked disks': 32 nodes from its shape alone
    lines = choices(OptimizeConfig(), settle(OptimizeConfig(), box, 0.19), box, dataset, 0.19)
    assert "fringes denser than the pixels in 19% of the specimen's pixels (up to 2.5 orders per pixel)" in lines[0]
    assert "elevations spanning" in lines[0]
    assert lines[1].startswith("chose: grid 64x64x20 (the finest default: the fringes alias in more than 10% of")
    finer = choices(OptimizeConfig(), settle(OptimizeConfig(), box, 0.08, pixels=128), box, dataset, 0.08, 128)
    assert "more than 10% of the pixels at 64 across (about 16%; 8% at 128)" in finer[1]
    assert "eased above a field RMS of 0.5 stress scales, for dense fringes" in lines[1]
    assert "; no neighbour loss (the fringes alias in more than 10% of the pixels); " in lines[1]
    # The neighbour loss reads the share as the grid does: at 128 px it broke the 300 N and stacked disks, whose
    # fringes alias in 7% and 8% of those pixels (docs/reconstruction.md, "The neighbour loss").
    assert "; no neighbour loss (the fringes alias in more than 10% of the pixels at 64 across (about 16%; 8% at " \
           "128)); " in finer[1]


def test_a_node_on_the_surface_counts_the_share_of_its_cells_inside_and_is_trusted_less(tmp_path):
    from mi_nest.reconstruct.equilibrium import CellStencil
    from mi_nest.reconstruct.trust import inside_share
    occupied = np.zeros((4, 5, 6), bool)         # cells (z, y, x) of a 7 x 6 x 5 node grid
    occupied[1:3, 1:4, 1:5] = True               # a block of 2 x 3 x 4 cells
    share = inside_share(CellStencil.of((7, 6, 5), np.ones(3), occupied))
    # Deep inside all eight cells, on a face four, on an edge two, at a corner one, off the block none.
    assert share[2, 2, 2] == 1.0 and share[2, 2, 1] == 0.5 and share[1, 1, 3] == 0.25 and share[1, 1, 1] == 0.125
    assert share[0].max() == 0.0 and share.sum() == pytest.approx(occupied.sum())
    values = np.full(share.shape, 2.0)
    trust = TrustMap(np.zeros(3), np.ones(3), values, values, values, values, [], [], None, share)
    assert trust.uncertainty[2, 2, 2] == 2.0 and trust.uncertainty[1, 1, 1] == 16.0
    assert np.isnan(trust.uncertainty[0]).all()
    trust.save(tmp_path / TRUST_FILE)
    np.testing.assert_array_equal(TrustMap.load(tmp_path / TRUST_FILE).uncertainty, trust.uncertainty)


def test_the_seed_spread_is_the_root_mean_square_difference_over_root_two_and_scales_the_uncertainty():
    from mi_nest.reconstruct.trust import seed_spread
    step = np.zeros(6)
    step[[0, 1, 3]] = (1.0, -1.0, 0.5)          # a deviator (xx, yy, zz, xy, yz, zx): |step| = sqrt(2.5) MPa
    grids = [disk_deviator_grid(lambda truth, nodes, k=k: truth + k * step)[0] for k in (0, 1, 2)]
    nodes = disk_deviator_grid()[1][::97]
    size = np.sqrt(2.5)
    # The middle run is one step from each other, the first one and two: sqrt((1 + 4) / 2 / 2) steps.
    np.testing.assert_allclose(seed_spread(grids[1], [grids[0], grids[2]], nodes), size / np.sqrt(2), rtol=1e-4)
    np.testing.assert_allclose(seed_spread(grids[0], [grids[1], grids[2]], nodes), size * np.sqrt(5) / 2,
                               rtol=1e-4)
    values = np.full((2, 2, 2), 3.0)
    spread = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 2.0, 4.0, 4.0]).reshape(2, 2, 2)
    trust = TrustMap(np.zeros(3), np.ones(3), values, values, values, values, [], [], None, np.ones((2, 2, 2)),
                     spread)
    # Times one plus the spread over its median (1.0): where the runs disagree four times as much, 2.5 times as
    # uncertain as where they disagree as much as usual.
    np.testing.assert_array_equal(trust.uncertainty, 3.0 * (1.0 + spread))


def test_mi_nest_spread_gives_each_run_the_others_spread_and_refuses_what_it_cannot_compare(
        one_axis_and_two_axes, tmp_path, capsys):
    import shutil

    from mi_nest.cli import main
    scene = mi_nest.load_scene("disk_compression", res=16, load=20)
    runs = {}
    for name, data, seed in (("a", "two", 0), ("b", "two", 1), ("other_data", "one", 1)):
        optimize(scene, one_axis_and_two_axes[data], output=tmp_path / name, progress=False, iterations=3,
                 batch_size=64, resolution=8, evaluate_views=1, seed=seed)
        runs[name] = tmp_path / name
    shutil.copytree(runs["a"], tmp_path / "copy_of_a")
    shutil.copytree(runs["b"], tmp_path / "without_trust")
    (tmp_path / "without_trust" / TRUST_FILE).unlink()
    before = (runs["a"] / TRUST_FILE).read_bytes()
    refusals = {"one run": [runs["a"]], "given twice": [runs["a"], runs["a"]],
                "another dataset": [runs["a"], runs["other_data"]], "a copy": [runs["a"], tmp_path / "copy_of_a"],
                "no result": [runs["a"], tmp_path / "nothing"], "no trust map": [runs["a"], tmp_path / "without_trust"]}
    expected = {"one run": "compares two or more reconstructions of one dataset, got 1",
                "given twice": "is given twice", "another dataset": "a seed spread compares runs of one dataset",
                "a copy": "holds the same field as the other runs", "no result": "is not a reconstruction",
                "no trust map": "has no trust map (trust.npz): run the mi-nest reconstruct command"}
    for case, directories in refusals.items():
        assert main(["spread", *map(str, directories)]) == 2, case
        error = capsys.readouterr().err
        assert error.count("\n") == 1 and expected[case] in error, (case, error)
        assert (runs["a"] / TRUST_FILE).read_bytes() == before, case
    assert main(["spread", str(runs["a"]), str(runs["b"])]) == 0
    printed = capsys.readouterr().out
    assert "seed spread over 1 other run(s)" in printed and "it ranks the actual deviatoric error at Spearman" in printed
    trusts = [TrustMap.load(runs[name] / TRUST_FILE) for name in "ab"]
    fields = [Reconstruction.load(runs[name]).field for name in "ab"]
    measured = np.isfinite(trusts[0].imbalance)
    nodes = trusts[0].nodes()[measured.ravel()]
    difference = tensor_norm(deviatoric_part(sample(fields[0], nodes)) - deviatoric_part(sample(fields[1], nodes)))
    np.testing.assert_allclose(trusts[0].seed_spread[measured], difference / np.sqrt(2), rtol=1e-5)
    np.testing.assert_allclose(trusts[1].seed_spread[measured], trusts[0].seed_spread[measured], rtol=1e-5)
    plain = trusts[0].imbalance / trusts[0].inside_share
    np.testing.assert_allclose(trusts[0].uncertainty[measured], (plain * (1 + trusts[0].seed_spread / np.median(
        trusts[0].seed_spread[measured])))[measured])
    summary = json.loads((runs["a"] / "reconstruction.json").read_text())["metrics"]["trust"]
    assert summary["seed_spread_from"] == [str(runs["b"].resolve())]
    assert summary["seed_spread_median"] == pytest.approx(float(np.median(trusts[0].seed_spread[measured])))
    described = Reconstruction.load(runs["a"]).describe()
    assert "times one plus its seed spread over the median" in described and "given to mi-nest spread" not in described
