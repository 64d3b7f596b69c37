"""Branch repair: the regions that nodes out of equilibrium enclose are found and refilled from around them."""
import json

import numpy as np
import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.fields.base import sample
from mi_nest.io.grid import StressGrid, grid_nodes, save_stress_grid
from mi_nest.reconstruct import metrics, optimize
from mi_nest.reconstruct.fields import stored_components
from mi_nest.reconstruct.repair import SMALLEST_HOLE, enclosed_region, harmonic_fill
from mi_nest.reconstruct.trust import imbalance
from mi_nest.scene import specimen_shapes
from scenes import disk_deviator_grid, tiny_disk

LOAD = 100
BOX = (np.array([-20.0, -20.0, -3.0]), np.array([20.0, 20.0, 3.0]))


def _lens(points):
    """The nodes of a lens about the disk's centre, where a descent on a wrong branch sits."""
    return (points[:, 0] / 4.0) ** 2 + (points[:, 1] / 10.0) ** 2 < 1.0


def _shifted(stress, where):
    """``stress`` (3D-TSV order) with a uniform in-plane shear added at ``where``, as large as the disk centre's
    ``(xx - yy) / 2``: balanced inside, and at the rim a jump of tangential traction that no mean stress balances,
    as on a branch a fringe order off."""
    shifted = stress.copy()
    shifted[where, 5] += 0.5 * np.abs(stress[where, 0] - stress[where, 1]).mean()
    return shifted


def test_the_harmonic_fill_gives_back_a_linear_field():
    z, y, x = np.meshgrid(*(np.arange(n, dtype=float) for n in (6, 9, 11)), indexing="ij")
    linear = np.stack([x + 2 * y - z, 0.5 * z - y + 3.0], axis=-1)
    unknown = np.zeros(x.shape, dtype=bool)
    unknown[1:5, 2:7, 3:9] = True
    filled = harmonic_fill(np.where(unknown[..., None], 100.0, linear), unknown)
    assert np.abs(filled - linear).max() < 1e-9
    assert np.array_equal(filled[~unknown], linear[~unknown])


def _ringed(radius, gap=False):
    """An imbalance of 1 on a disk of nodes (NaN outside), 20 on a ring of ``radius`` (open with ``gap``)."""
    z, y, x = np.meshgrid(np.arange(5), np.arange(41) - 20.0, np.arange(41) - 20.0, indexing="ij")
    r = np.hypot(x, y)
    balance = np.where(r < 20, 1.0 + 0.1 * np.cos(x * y), np.nan)
    ring = (np.abs(r - radius) < 1.0) & ~(gap & (x > 0) & (np.abs(y) < 2))
    balance[ring] = 20.0
    return balance, r


def test_a_ring_of_unbalanced_nodes_marks_what_it_encloses_and_an_open_one_nothing():
    balance, r = _ringed(8.0)
    region, count = enclosed_region(balance)
    assert count == 1
    assert region[r < 7].all()                     # the hole, in every plane
    assert region[np.abs(r - 8) < 1].all()         # and the ring around it
    assert not region[r > 12].any()
    assert not enclosed_region(_ringed(8.0, gap=True)[0])[0].any()
    # A hole smaller than SMALLEST_HOLE of the part is left alone (a contact's few nodes).
    small, r = _ringed(1.2)
    assert (r[np.isfinite(small)] < 1).mean() < SMALLEST_HOLE
    assert enclosed_region(small)[1] == 0


def test_a_shifted_lens_in_the_disk_is_found_and_refilled_nearer_the_truth():
    scene = mi_nest.load_scene("disk_compression", res=8, load=LOAD, contact_width=4)
    exact, _, _ = disk_deviator_grid()
    assert enclosed_region(imbalance(scene, exact, exact.shape))[1] == 0     # the truth: nothing to repair
    grid, nodes, truth = disk_deviator_grid(lambda deviator, nodes: _shifted(deviator, _lens(nodes)))
    balance = imbalance(scene, grid, grid.shape)
    region, count = enclosed_region(balance)
    lens = _lens(nodes).reshape(balance.shape) & np.isfinite(balance)
    assert count >= 1 and region[lens].mean() > 0.9
    assert region.sum() < 3 * lens.sum()
    filled = harmonic_fill(grid.nodes().reshape(*balance.shape, 5), region).reshape(-1, 5)
    stored = stored_components(truth, grid.stress_scale)
    before = np.linalg.norm(grid.nodes()[lens.ravel()] - stored[lens.ravel()])
    after = np.linalg.norm(filled[lens.ravel()] - stored[lens.ravel()])
    assert after < before / 3


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    return tiny_disk(tmp_path_factory.mktemp("data") / "disk", LOAD)


def test_a_run_started_on_a_shifted_lens_repairs_it_records_and_prints_it(tiny_dataset, tmp_path, capsys):
    scene = mi_nest.load_scene("disk_compression", res=8, load=LOAD)
    counts = (48, 48, 8)
    points = grid_nodes(*BOX, counts)
    stress = _shifted(sample(scene.shapes()[0].interior_medium().field, points), _lens(points))
    start = tmp_path / "shifted.npz"
    save_stress_grid(start, StressGrid(stress.reshape(*counts[::-1], 6).astype(np.float32), *BOX))
    # Steps far below the field's scale: the result is where the run started, repaired or not.
    still = dict(iterations=10, learning_rate=1e-6, final_learning_rate=1e-6, batch_size=64, views_per_batch=3,
                 resolution=32, kind="grid", evaluate_views=1, pixel_samples=1, average_last=0.0,
                 start_scale_range=0.0, start=str(start))
    inside = metrics.evaluation_points(scene, specimen_shapes(scene))
    probe = metrics.ErrorProbe(scene.shapes()[0].interior_medium().field, inside[_lens(inside)])
    errors = {}
    for every in (0.0, 0.1):
        output = tmp_path / f"every{every}"
        with pytest.warns(RuntimeWarning):
            result = optimize(scene, tiny_dataset, output=output, progress=True, branch_repair=every, **still)
        errors[every] = probe(result.field)
        repairs = [entry for entry in result.history if "repair" in entry]
        printed = [line for line in capsys.readouterr().out.splitlines() if line.startswith("branch repair")]
        recorded = json.loads((output / "reconstruction.json").read_text())["source"]["choices"]
        if every == 0.0:
            assert not repairs and not printed
            continue
        # The first check, at a tenth of the run, refills the lens; the refilled field leaves nothing to repair.
        assert [entry["iteration"] for entry in repairs] == [1]
        assert 0 < repairs[0]["repair"]["share"] < 0.5
        assert printed == [line for line in recorded if line.startswith("branch repair")]
        assert printed[0].startswith("branch repair at 10% of the run (iteration 1): refilled ")
    assert errors[0.1] < errors[0.0] / 3       # in the lens


def test_a_repair_share_outside_0_to_1_is_refused(tiny_dataset, tmp_path, capsys):
    assert main(["reconstruct", str(tiny_dataset), "-o", str(tmp_path / "run"), "--allow-aliased",
                 "--no-progress", "--option", "branch_repair=1.5"]) == 2
    error = capsys.readouterr().err.strip()
    assert "'branch_repair' is a share of the run in [0, 1], got 1.5" in error and "\n" not in error
    assert not (tmp_path / "run" / "reconstruction.json").exists()
