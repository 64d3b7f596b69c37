"""The neighbour loss (reconstruct/neighbours.py): the rotation between neighbouring pixels' Jones matrices,
recovered from the measurements and traced through a field, and the landscape it gives along the load."""
import numpy as np
import pytest

import mi_nest
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.physics import su2
from mi_nest.physics.recovery import jones_and_polarisation
from mi_nest.reconstruct import optimize
from mi_nest.reconstruct.channels import ChannelModel
from mi_nest.reconstruct.config import NEIGHBOUR_WEIGHT, TWO_STEP, OptimizeConfig
from mi_nest.reconstruct.fields import settle
from mi_nest.reconstruct.losses import l1_loss
from mi_nest.reconstruct.neighbours import NeighbourTargets, neighbours
from mi_nest.reconstruct.rays import ViewRays
from mi_nest.scene import scene_tracer
from mi_nest.tracer import View

# A noiseless disk whose fringes the 32 pixels resolve in 90% of its pixels, with several fringes along the loaded
# diameter: its intensities wrap along the load, its neighbours' rotations do not. Each pixel the mean of 16 rays
# over its area, as a camera integrates it.
LOAD = 150
SETTINGS = SimulationSettings(azimuths=2, elevations=2, res=32, spp=16, test_fraction=0.25)


@pytest.fixture(scope="module")
def disk(tmp_path_factory):
    directory = tmp_path_factory.mktemp("neighbours") / "disk"
    simulate("disk_compression", directory, SETTINGS, progress=False, defines={"load": LOAD, "contact_width": 4})
    return mi_nest.Dataset(directory), mi_nest.load_scene("disk_compression", res=32, load=LOAD, contact_width=4)


def _batch(dataset, count=4096, seed=0):
    """``(pixels, their measurements, pairs of each pixel and a neighbour)``."""
    rng = np.random.default_rng(seed)
    positions, rows, columns, targets = dataset.ray_batch(count, rng, views_per_batch=3)
    return (positions, rows, columns), targets, NeighbourTargets(dataset).pairs(positions, rows, columns, rng)


def _traced(scene, dataset, pixels, phase_scale=1.0):
    """The scene's own field traced through the centres of ``pixels``: its Jones quaternions (NumPy)."""
    rays, right = ViewRays(scene, dataset).rays(*pixels)
    traced = scene_tracer(scene).trace_rays(scene, rays, right, view=View(phase_scale=phase_scale))
    return traced.jones()


def test_a_neighbour_is_one_of_the_four_and_inside_the_image():
    rng = np.random.default_rng(1)
    rows, columns = rng.integers(0, 5, 500), rng.integers(0, 7, 500)
    next_rows, next_columns = neighbours(rows, columns, (7, 5), rng)
    assert np.all(np.abs(next_rows - rows) + np.abs(next_columns - columns) == 1)
    assert next_rows.min() >= 0 and next_rows.max() < 5 and next_columns.min() >= 0 and next_columns.max() < 7
    # Every direction is drawn.
    assert len({(int(r), int(c)) for r, c in zip(next_rows - rows, next_columns - columns)}) == 4


def test_a_pixel_that_averages_two_jones_matrices_keeps_less_light_polarised():
    scopes = tuple(mi_nest.physics.MEASUREMENTS.values())
    rng = np.random.default_rng(2)
    q = rng.normal(size=(2, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    one = np.array([scope.intensity(tuple(q[0])) for scope in scopes])
    other = np.array([scope.intensity(tuple(q[1])) for scope in scopes])
    recovered, polarisation = jones_and_polarisation(np.stack([one, (one + other) / 2]), scopes)
    assert abs(abs(recovered[0] @ q[0]) - 1) < 1e-9 and polarisation[0] == pytest.approx(1.0, abs=1e-12)
    # Two Jones matrices averaged: the pixel's light is partly depolarised, by as much as they differ.
    assert polarisation[1] < 1 - 0.1 * (1 - abs(q[0] @ q[1]))


def test_the_measured_rotation_between_neighbours_is_the_traced_one(disk):
    dataset, scene = disk
    _, _, pairs = _batch(dataset)
    q = np.stack([np.array(x) for x in _traced(scene, dataset, pairs.pixels)], axis=-1)
    count = len(pairs.measured)
    traced = np.stack(su2.multiply(su2.conjugate(tuple(q[:count].T)), tuple(q[count:].T)), axis=-1)
    angle = 2 * np.arccos(np.clip(np.abs(np.sum(traced * pairs.measured, axis=-1)), 0, 1))
    turn = 2 * np.arccos(np.clip(np.abs(pairs.measured[:, 0]), 0, 1))
    # Where both pixels keep their light polarised (the fringes resolved within them), the rotation recovered from
    # the pixels' mean intensities is the one between the rays through their centres, to a small part of the turn.
    resolved = pairs.weights > 0.9
    assert resolved.mean() > 0.1
    assert np.median(angle[resolved]) < 0.15 * np.median(turn[resolved])
    assert np.quantile(angle[resolved], 0.9) < 0.15
    # Where a pixel averages fringes, less of its light stays polarised, and its pairs weigh less.
    assert np.median(angle[pairs.weights < 0.3]) > 3 * np.median(angle[resolved])


def test_from_zero_the_neighbour_loss_falls_to_the_truth_where_the_intensities_wrap(disk):
    """Along the line from the zero field to the truth (its phases scaled), the intensities' loss has wrapped
    minima and the neighbour loss none."""
    dataset, scene = disk
    pixels, targets, pairs = _batch(dataset)
    channels = ChannelModel.of(dataset, scene)
    intensity, neighbour = [], []
    for scale in np.linspace(0.0, 1.0, 21):
        scale = max(scale, 1e-6)
        intensity.append(float(l1_loss(_traced(scene, dataset, pixels, scale), targets, 1, None, channels)[0]))
        neighbour.append(float(pairs.loss(_traced(scene, dataset, pairs.pixels, scale), 0)[0]))
    # A descent from zero along the line would have to climb the intensities' loss (+0.011 here), not the other.
    assert np.max(intensity - np.minimum.accumulate(intensity)) > 0.005, intensity
    assert np.all(np.diff(neighbour) < 0), neighbour
    assert neighbour[-1] < 0.2 * neighbour[0]


def test_options_and_data_the_neighbour_loss_cannot_take_are_refused(disk, tmp_path):
    dataset, scene = disk
    with pytest.raises(ValueError, match="neighbour_loss must be a non-negative weight"):
        optimize(scene, dataset.directory, progress=False, neighbour_loss=-1.0)
    with pytest.raises(ValueError, match="'neighbour_share' is a share of the run in \\(0, 1\\]"):
        optimize(scene, dataset.directory, progress=False, neighbour_loss=1.0, neighbour_share=0.0)
    banded = tmp_path / "bands"
    simulate("disk_compression", banded, SimulationSettings(azimuths=2, elevations=1, res=8, spp=1,
                                                             bands="450,650"), progress=False,
             defines={"load": 20})
    with pytest.raises(ValueError, match="neighbour_loss compares the Jones quaternions of straight rays at one "
                                         "wavelength"):
        optimize(mi_nest.load_scene("disk_compression", res=8, load=20), banded, progress=False, iterations=2,
                 batch_size=32, resolution=6, evaluate_views=1, neighbour_loss=1.0)
    with pytest.warns(RuntimeWarning, match="ior"), pytest.raises(ValueError, match="or its scene refracts"):
        optimize(mi_nest.load_scene("disk_compression", res=32, load=LOAD, contact_width=4, ior=1.55),
                 dataset.directory, progress=False, iterations=2, batch_size=32, resolution=6, evaluate_views=1,
                 neighbour_loss=1.0)


def test_the_defaults_fit_the_neighbour_loss_where_it_applies_and_the_fringes_are_resolved(disk, tmp_path):
    dataset, scene = disk
    extent = np.array([40.0, 40.0, 6.0])
    settled = settle(OptimizeConfig(), extent, aliased_share=0.05)
    assert settled.optimiser.neighbour_loss == NEIGHBOUR_WEIGHT
    # Dense fringes (the same share of 128-pixel images is denser at 64), the Two-step, a weight given, and a scene
    # or data it cannot take.
    assert settle(OptimizeConfig(), extent, aliased_share=0.15).optimiser.neighbour_loss == 0.0
    assert settle(OptimizeConfig(), extent, aliased_share=0.06, pixels=128).optimiser.neighbour_loss == 0.0
    assert settle(OptimizeConfig(method=TWO_STEP), extent).optimiser.neighbour_loss == 0.0
    assert settle(OptimizeConfig(neighbour_loss=0.3), extent, aliased_share=0.15).optimiser.neighbour_loss == 0.3
    assert settle(OptimizeConfig(), extent, neighbours_apply=False).optimiser.neighbour_loss == 0.0
    quick = dict(progress=False, iterations=2, batch_size=32, resolution=6, evaluate_views=1)
    on = optimize(scene, dataset.directory, **quick)
    assert on.config.optimiser.neighbour_loss == NEIGHBOUR_WEIGHT
    assert "the neighbour loss at weight 1 over the first 50% of the run (the fringes resolved" \
        in on.source["choices"][1]
    with pytest.warns(RuntimeWarning, match="ior"):
        refracted = optimize(mi_nest.load_scene("disk_compression", res=32, load=LOAD, contact_width=4, ior=1.55),
                             dataset.directory, **quick)
    assert refracted.config.optimiser.neighbour_loss == 0.0
    assert "no neighbour loss (the scene refracts or the data have bands)" in refracted.source["choices"][1]


def test_the_recovered_views_kept_stay_within_the_dataset_s_own_cache(disk):
    dataset, _ = disk
    width, height = dataset.resolution
    view_bytes = 16 * 4 * width * height
    small = mi_nest.Dataset(dataset.directory, cache_bytes=2 * view_bytes)
    targets, unbounded = NeighbourTargets(small), NeighbourTargets(dataset)
    assert targets.views_kept == 2 and unbounded.views_kept >= len(dataset)
    first = targets.view(0).copy()
    for position in (1, 2, 0):
        targets.view(position)
        assert len(targets._views) <= 2
    np.testing.assert_array_equal(targets.view(0), first)
    np.testing.assert_array_equal(unbounded.view(0), first)
