"""Reconstruction: trainable fields, metrics, the optimiser (smoke, resume, divergence, options), CLI."""
import json
from dataclasses import replace
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mi_nest
from mi_nest import occupancy
from mi_nest.cli import main
from mi_nest.dataset import simulate
from mi_nest.fields import UniformField
from mi_nest.io.grid import grid_nodes
from mi_nest.reconstruct import (NO_REGULARISER, REGULARISED, DivergenceError, FieldConfig, OptimizeConfig,
                                 Reconstruction, Regulariser, make_field, optimize)
from mi_nest.reconstruct import loop, metrics
from mi_nest.reconstruct.evaluation import dataset_loss
from mi_nest.reconstruct.fields import (DEFAULT_RESOLUTIONS, MIN_NODES_ACROSS, choose_kind, default_resolution,
                                       grid_shape, refined, settle, stored_components)
from mi_nest.scene import specimen_bounds, specimen_shapes
from mi_nest.tracer import Tracer, TracerConfig
from scenes import TINY

FAST = dict(iterations=3, batch_size=64, views_per_batch=3, learning_rate=0.1, resolution=6, evaluate_views=1,
            pixel_samples=1)


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    directory = tmp_path_factory.mktemp("data") / "disk"
    with pytest.warns(RuntimeWarning):
        simulate("disk_compression", directory, TINY, progress=False, defines={"load": 200})
    return directory


def _scene():
    return mi_nest.load_scene("disk_compression", res=8, load=200)


@pytest.mark.parametrize("name", ["disk_compression", "twisted_block"])    # orthographic, perspective
def test_batch_rays_are_the_camera_s_rays_at_each_rotation(name, tmp_path):
    from mi_nest.reconstruct.rays import ViewRays
    from mi_nest.scene import pose, reference_pose
    simulate(name, tmp_path, TINY, progress=False)
    dataset = mi_nest.Dataset(tmp_path)
    scene = mi_nest.load_scene(name, res=8)
    sensor = scene.sensors()[0]
    rng = np.random.default_rng(1)
    positions, rows, columns = rng.integers(0, len(dataset), 200), rng.integers(0, 8, 200), rng.integers(0, 8, 200)
    jitter = rng.random((200, 2))
    rays, right = ViewRays(scene, dataset).rays(positions, rows, columns, jitter)
    origins, directions, rights = (np.array(x).T for x in (rays.o, rays.d, right))
    reference = reference_pose(scene)
    for position in range(len(dataset)):
        chosen = positions == position
        pose(scene, dataset.to_world(position))
        film = np.stack([(columns[chosen] + jitter[chosen, 0]) / 8, (rows[chosen] + jitter[chosen, 1]) / 8])
        expected, _ = sensor.sample_ray(0.0, 0.0, mi.Point2f(film.astype(np.float32)), mi.Point2f(0.5, 0.5))
        shape = origins[chosen].shape
        np.testing.assert_allclose(origins[chosen], np.broadcast_to(np.array(expected.o).T, shape), atol=1e-4)
        np.testing.assert_allclose(directions[chosen], np.broadcast_to(np.array(expected.d).T, shape), atol=1e-6)
        axis = -dataset.to_world(position)[:3, 0]
        np.testing.assert_allclose(rights[chosen], np.broadcast_to(axis / np.linalg.norm(axis), shape), atol=1e-6)
    pose(scene, reference)
    assert len(np.unique(positions)) == len(dataset) > 1


@pytest.mark.parametrize("kind", ["grid", "hashgrid", "mlp"])
def test_fields_are_trace_free_and_survive_a_save(kind, tmp_path):
    config = FieldConfig(kind=kind, resolution=5, levels=2, hashmap_size=256, width=8, layers=1, octaves=2)
    field = make_field(config, (-1, -2, -3), (1, 2, 3), 2.5)
    rng = np.random.default_rng(0)
    field.assign({n: type(v)(rng.normal(size=v.shape).astype(np.float32)) for n, v in field.parameters().items()})
    points = rng.uniform(-1, 1, (50, 3)) * [1, 2, 3]
    values = metrics.sample(field, points)
    np.testing.assert_allclose(values[:, 0] + values[:, 1] + values[:, 2], 0, atol=1e-5 * np.abs(values).max())
    result = Reconstruction(field, OptimizeConfig(field=config), [{"iteration": 0, "loss": 1.0}], {}, 0.0)
    loaded = Reconstruction.load(result.save(tmp_path / kind))
    np.testing.assert_array_equal(metrics.sample(loaded.field, points), values)
    assert loaded.field.describe() == field.describe()


@pytest.mark.parametrize("kind", ["hashgrid", "mlp"])
def test_a_network_sampled_on_a_lattice_is_the_network_at_its_nodes_and_trilinear_between(kind):
    config = FieldConfig(kind=kind, resolution=5, levels=2, hashmap_size=256, width=8, layers=1, octaves=2)
    sampled, every_step = (make_field(c, (-1, -2, -3), (1, 2, 3), 2.5) for c in (config, replace(config, resolution=0)))
    rng = np.random.default_rng(4)
    values = {n: type(v)(rng.normal(size=v.shape).astype(np.float32)) for n, v in sampled.parameters().items()}
    sampled.assign(values)
    every_step.assign(values)
    assert (sampled.lattice, every_step.lattice, every_step.shape) == (True, False, None)
    nodes = grid_nodes(sampled.bbox_min, sampled.bbox_max, sampled.shape)
    exact = metrics.sample(every_step, nodes)
    np.testing.assert_allclose(metrics.sample(sampled, nodes), exact, atol=1e-5 * np.abs(exact).max())
    # Halfway between neighbouring nodes along each axis: their mean, where the network itself is not.
    nx, ny, nz = sampled.shape
    on_lattice, at_nodes = nodes.reshape(nz, ny, nx, 3), exact.reshape(nz, ny, nx, 6)
    for axis in (2, 1, 0):
        ends = [np.take(a, range(e, a.shape[axis] - 1 + e), axis=axis).reshape(-1, a.shape[-1])
                for a in (on_lattice, at_nodes) for e in (0, 1)]
        middle = metrics.sample(sampled, (ends[0] + ends[1]) / 2)
        np.testing.assert_allclose(middle, (ends[2] + ends[3]) / 2, atol=1e-5 * np.abs(exact).max())
        assert np.abs(metrics.sample(every_step, (ends[0] + ends[1]) / 2) - middle).max() > 1e-3
    # A finer stage keeps the field, as a grid's refinement does: the network is fitted on the finer nodes to the
    # coarser lattice's trilinear field, which it matches far better than the network as it was.
    finer = grid_nodes(sampled.bbox_min, sampled.bbox_max, grid_shape(9, (2, 4, 6)))
    coarse_field = metrics.sample(sampled, finer)
    sampled.sample_on(9, learning_rate=0.01 if kind == "mlp" else 0.05)
    assert sampled.shape == grid_shape(9, (2, 4, 6)) and sampled.config.resolution == 9
    kept = np.abs(metrics.sample(sampled, finer) - coarse_field).max()
    assert kept < 0.3 * np.abs(metrics.sample(every_step, finer) - coarse_field).max()
    # What the rays see is still the network at the nodes.
    every_step.assign(sampled.parameters())
    np.testing.assert_allclose(metrics.sample(sampled, finer), metrics.sample(every_step, finer),
                               atol=1e-5 * np.abs(exact).max())


@pytest.mark.parametrize("kind", ["hashgrid", "mlp"])
def test_a_lattice_samples_by_matrix_products_and_a_step_by_cooperative_vectors_share_their_gradients(kind):
    """The lattice's samples are computed by matrix products on the weights gathered from the packed buffer; their
    backward pass must reach the same buffer with what the cooperative vectors of a ray's step give."""
    field = make_field(FieldConfig(kind=kind, resolution=6, levels=2, hashmap_size=256, width=16, layers=2,
                                   octaves=3), (-1, -2, -3), (1, 2, 3), 2.5)
    points = mi.Point3f(np.random.default_rng(5).uniform(-1, 1, (3, 97)).astype(np.float32))
    weights = [mi.Float(np.random.default_rng(6 + c).normal(size=97).astype(np.float32)) for c in range(5)]
    gradients = []
    for evaluate in (field.network, field.network_at_all):
        parameters = field.parameters()
        for value in parameters.values():
            dr.enable_grad(value)
            dr.clear_grad(value)
        with dr.resume_grad():
            values = evaluate(points)
            dr.backward(sum(dr.sum(v * w) for v, w in zip(values, weights)))
        gradients.append({name: np.array(dr.grad(value)) for name, value in parameters.items()})
    for name, by_vectors in gradients[0].items():
        assert np.abs(by_vectors).max() > 0
        np.testing.assert_allclose(gradients[1][name], by_vectors, atol=1e-5 * np.abs(by_vectors).max())


@pytest.mark.parametrize("kind", ["grid", "hashgrid", "mlp"])
def test_fields_stay_bounded_a_hair_outside_their_box(kind):
    """Samples on a specimen's surface can round outside the bounding box (the hash encoding then read
    outside its tables: values of 1e26 ended an experiment as NaN)."""
    field = make_field(FieldConfig(kind=kind, resolution=8, width=8, layers=1), (-1, -2, -3), (1, 2, 3), 1.0)
    rng = np.random.default_rng(1)
    inside = rng.uniform(-1, 1, (2000, 3)) * [1, 2, 3]
    outside = inside * (1 + rng.uniform(0, 0.02, (2000, 1)))
    values, near = metrics.sample(field, outside), metrics.sample(field, inside)
    assert np.isfinite(values).all() and np.abs(values).max() < 10 * np.abs(near).max() + 1e-6


def test_auto_picks_the_grid_until_it_grows_too_large():
    assert choose_kind(FieldConfig(resolution=64), (40, 40, 6)) == "grid"
    assert choose_kind(FieldConfig(resolution=256), (40, 40, 40)) == "hashgrid"
    assert choose_kind(FieldConfig(kind="mlp"), (1, 1, 1)) == "mlp"
    assert grid_shape(5, (4.0, 2.0, 1.0)) == (5, 3, 2)


@pytest.mark.parametrize("extent, resolution", [((59.9, 54.3, 91.9), 32), ((40, 40, 12), 32), ((40, 40, 10), 48),
                                                 ((40, 40, 6), 64), ((40, 40, 1), 64)],
                         ids=["kitten", "stacked disks", "lame cylinder", "disk", "foil"])
def test_the_default_grid_puts_ten_nodes_across_the_thinnest_side(extent, resolution):
    """The kitten met its target at 32 nodes along its longest axis, the 6 mm disk only at 64."""
    assert default_resolution(extent) == resolution
    shape = grid_shape(resolution, extent)
    assert min(shape) >= MIN_NODES_ACROSS or resolution == DEFAULT_RESOLUTIONS[-1]
    assert resolution == DEFAULT_RESOLUTIONS[0] or min(grid_shape(resolution - 16, extent)) < MIN_NODES_ACROSS


def test_the_defaults_settle_on_a_specimen():
    """The kind, the resolution and the regulariser a run records are what it did, never 'auto'."""
    settled = settle(OptimizeConfig(), np.array([40.0, 40.0, 6.0]))
    assert (settled.field.kind, settled.field.resolution, settled.regulariser) == ("grid", 64, REGULARISED)
    # Too many nodes for a grid: a hash grid evaluated at every step (a lattice as large would not fit either), and
    # the grids' regulariser is not carried over to it.
    large = settle(OptimizeConfig(resolution=256), np.array([40.0, 40.0, 40.0]))
    assert (large.field.kind, large.field.resolution, large.regulariser) == ("hashgrid", 0, NO_REGULARISER)
    with pytest.raises(ValueError, match="evaluated at every step"):
        settle(OptimizeConfig(resolution=256, smoothness=1e-3), np.array([40.0, 40.0, 40.0]))
    with pytest.raises(ValueError, match="a grid at 256 nodes would be too large here"):
        settle(OptimizeConfig(resolution=256, start="model.TSV"), np.array([40.0, 40.0, 40.0]))
    assert settle(OptimizeConfig(resolution=20), np.array([40.0, 40.0, 6.0])).field.resolution == 20
    # The stacked disks' box: 32 nodes put 11 across its 12 mm; fringes aliased in 19% of the pixels ask for 64,
    # past the share reconstruct refuses without --allow-aliased; a resolution given is kept.
    stacked = np.array([40.0, 40.0, 12.0])
    assert settle(OptimizeConfig(), stacked, aliased_share=0.09).field.resolution == 32
    assert settle(OptimizeConfig(), stacked, aliased_share=0.19).field.resolution == 64
    assert settle(OptimizeConfig(resolution=32), stacked, aliased_share=0.19).field.resolution == 32
    # There the grids' default smoothness eases from half the field RMS; a regulariser given is kept.
    from mi_nest.reconstruct.config import DENSE_REGULARISED
    assert settle(OptimizeConfig(), stacked, aliased_share=0.19).regulariser == DENSE_REGULARISED
    assert DENSE_REGULARISED == replace(REGULARISED, relative_to=0.5)
    assert settle(OptimizeConfig(), stacked, aliased_share=0.09).regulariser == REGULARISED
    # Finer images alias in fewer of their pixels for the same fringes: 8% at 128 px reads as about 16% at 64.
    finer = settle(OptimizeConfig(), stacked, aliased_share=0.08, pixels=128)
    assert (finer.field.resolution, finer.regulariser) == (64, DENSE_REGULARISED)
    assert settle(OptimizeConfig(), stacked, aliased_share=0.08, pixels=64).field.resolution == 32
    # Coarser images' share is taken as it is.
    assert settle(OptimizeConfig(), stacked, aliased_share=0.19, pixels=8).field.resolution == 64
    assert settle(OptimizeConfig(regulariser=NO_REGULARISER), stacked, 0.19).regulariser == NO_REGULARISER
    assert settle(OptimizeConfig(smoothness=2e-4), stacked, 0.19).regulariser.relative_to == 1.0
    # A network sampled on a lattice takes the grids' regulariser; evaluated at every step, none.
    assert OptimizeConfig(kind="mlp").regulariser == OptimizeConfig(kind="hashgrid").regulariser == REGULARISED
    assert OptimizeConfig(kind="mlp", resolution=0).regulariser == NO_REGULARISER
    network = settle(OptimizeConfig(kind="hashgrid"), np.array([40.0, 40.0, 6.0]))
    assert (network.field.kind, network.field.resolution, network.regulariser) == ("hashgrid", 64, REGULARISED)
    with pytest.raises(ValueError, match="resolution must be at least 2"):
        OptimizeConfig(kind="grid", resolution=0)
    with pytest.raises(ValueError, match=r"resolution must be at least 2 nodes \(or 0: a network evaluated at every "
                                         r"step\), got 1"):
        OptimizeConfig(kind="mlp", resolution=1)
    # The MLP's own steps, smaller at every step (the grids' ran it away there); a learning rate given is kept, and a
    # saved run reloads as run.
    from mi_nest.reconstruct.config import MLP_EVERY_STEP_OPTIMISER, MLP_OPTIMISER, Optimiser
    assert OptimizeConfig(kind="mlp").optimiser == MLP_OPTIMISER
    assert OptimizeConfig(kind="mlp", resolution=0).optimiser == MLP_EVERY_STEP_OPTIMISER
    assert MLP_EVERY_STEP_OPTIMISER.learning_rate < MLP_OPTIMISER.learning_rate < Optimiser().learning_rate
    assert OptimizeConfig(kind="mlp", learning_rate=0.01).optimiser.learning_rate == 0.01
    assert OptimizeConfig(kind="grid").optimiser == OptimizeConfig(kind="hashgrid").optimiser == Optimiser()
    mlp = OptimizeConfig(kind="mlp", seed=2)
    assert OptimizeConfig.from_dict(mlp.to_dict()) == mlp and mlp.settled("mlp", 32).optimiser == mlp.optimiser
    assert OptimizeConfig(kind="mlp", resolution=0, average_last=0.2).regulariser == replace(NO_REGULARISER,
                                                                                              average_last=0.2)
    assert OptimizeConfig(kind="grid", smoothness=0.0).regulariser == replace(REGULARISED, smoothness=0.0)


@pytest.mark.parametrize("resolution, stages", [(6, [4, 6]), (16, [4, 8, 16]), (32, [8, 16, 32]),
                                                (64, [8, 16, 32, 64]), (96, [12, 24, 48, 96])])
def test_coarse_to_fine_starts_at_most_about_eight_nodes_across(tiny_dataset, resolution, stages):
    config = OptimizeConfig(field=FieldConfig(kind="grid", resolution=resolution))
    run = loop.Run(_scene(), mi_nest.Dataset(tiny_dataset), config, np.zeros(3), np.ones(3), 1.0, None, False)
    assert [r for _, r in run.stages] == stages
    starts = [s for s, _ in run.stages]
    assert starts[0] == 0 and starts[-1] == 0.5 and starts == sorted(starts)


def test_the_finest_stage_takes_its_share_and_its_own_rays_per_pixel(tiny_dataset):
    config = OptimizeConfig(iterations=100, field=FieldConfig(kind="grid", resolution=32), finest_stage=0.7,
                            coarse_pixel_samples=1, pixel_samples=3)
    run = loop.Run(_scene(), mi_nest.Dataset(tiny_dataset), config, np.zeros(3), np.ones(3), 1.0, None, False)
    assert run.stages == [(0.0, 8), (pytest.approx(0.15), 16), (pytest.approx(0.3), 32)]
    samples = {}
    for iteration in (0, 29, 31, 99):
        run.iteration = iteration
        samples[iteration] = run.pixel_samples()
    assert samples == {0: 1, 29: 1, 31: 3, 99: 3}
    # Without a coarse count every stage integrates the pixels alike: the dataset's spp (1 here).
    plain = loop.Run(_scene(), mi_nest.Dataset(tiny_dataset), OptimizeConfig(kind="grid", resolution=32),
                     np.zeros(3), np.ones(3), 1.0, None, False)
    assert plain.pixel_samples() == plain.finest_pixel_samples == 1
    for bad in (0.0, 1.5):
        with pytest.raises(ValueError, match="finest_stage"):
            OptimizeConfig(finest_stage=bad)
    with pytest.raises(ValueError, match="coarse_pixel_samples"):
        OptimizeConfig(coarse_pixel_samples=0)


def test_a_stage_marches_steps_of_half_its_own_grid_spacing(tiny_dataset):
    from mi_nest.reconstruct.forward import forward_step, make_tracer
    config = OptimizeConfig(field=FieldConfig(kind="grid", resolution=33))
    scene = _scene()
    for resolution in (9, 17, 33):
        field = make_field(FieldConfig(kind="grid", resolution=resolution), (0, 0, 0), (32, 16, 8), 1.0)
        assert forward_step(config, field) == pytest.approx(0.5 * 32 / (resolution - 1))
        assert make_tracer(config, field, scene).config.step_size == forward_step(config, field)
    given = OptimizeConfig(field=FieldConfig(kind="grid", resolution=33), step_size=0.25)
    assert make_tracer(given, field, scene).config.step_size == 0.25


def _assign_ramp_along_x(field, slope):
    """Every component of a cubic grid rising by ``slope`` across the box along x."""
    n = field.shape[0]
    ramp = np.broadcast_to(slope * np.linspace(0, 1, n)[None, None, :, None], (n, n, n, 5))
    field.assign({"grid": mi.TensorXf(np.ascontiguousarray(ramp, dtype=np.float32))})


def test_an_edge_spares_steep_gradients_and_keeps_gentle_ones_quadratic():
    def penalty(slope, edge):
        field = make_field(FieldConfig(kind="grid", resolution=9), (0, 0, 0), (10, 10, 10), 1.0)
        _assign_ramp_along_x(field, slope)
        return float(field.smoothness_penalty(1.0, edge)[0])

    quadratic = 0.02 ** 2 / 3                      # a third of the pairs (along x) see the slope
    assert penalty(0.02, edge=5.0) == pytest.approx(quadratic, rel=1e-4)
    # Far above the edge the penalty grows linearly: 2 edge |slope|, not slope^2.
    assert penalty(2000.0, edge=5.0) == pytest.approx(2 * 5.0 * 2000.0 / 3, rel=1e-2)
    assert penalty(4000.0, edge=5.0) / penalty(2000.0, edge=5.0) == pytest.approx(2.0, rel=1e-2)
    # Coarse stages keep the plain quadratic.
    assert penalty(2000.0, edge=None) == pytest.approx(2000.0 ** 2 / 3, rel=1e-5)


def test_smoothness_holds_through_the_coarse_stages_and_decays_geometrically_over_the_finest(tiny_dataset):
    regulariser = Regulariser(smoothness=1e-2, final_smoothness=1e-4)
    run = loop.Run(_scene(), mi_nest.Dataset(tiny_dataset),
                   OptimizeConfig(iterations=100, kind="grid", resolution=32, regulariser=regulariser),
                   np.zeros(3), np.ones(3), 1.0, None, False)
    weights = {}
    for iteration in (0, 30, 50, 75, 100):
        run.iteration = iteration
        weights[iteration] = regulariser.smoothness_at(run.smoothness_decayed())
    assert weights[0] == weights[30] == weights[50] == 1e-2
    assert weights[75] == pytest.approx(1e-3) and weights[100] == pytest.approx(1e-4)
    assert Regulariser(smoothness=1e-2).smoothness_at(0.7) == 1e-2
    for kind in ("hashgrid", "mlp"):
        OptimizeConfig(kind=kind, smoothness=1e-2)      # smoothed on the lattice they are sampled on
        with pytest.raises(ValueError, match="evaluated at every step"):
            OptimizeConfig(kind=kind, resolution=0, smoothness=1e-2)
    for final in (0.0, 2e-2):
        with pytest.raises(ValueError, match="final_smoothness"):
            Regulariser(smoothness=1e-2, final_smoothness=final)


def test_a_relative_regulariser_falls_with_the_square_of_the_field_scale_above_its_reference():
    """Above ``relative_to`` the weight falls as the RMS squared and the edge grows with it; below, both hold."""
    regulariser = Regulariser(smoothness=1e-2, smoothness_edge=5.0, relative_to=0.5)
    for rms in (None, 0.1, 0.5):
        assert regulariser.smoothness_at(0.0, rms) == 1e-2 and regulariser.edge_at(rms) == 5.0
    assert regulariser.smoothness_at(0.0, 1.5) == pytest.approx(1e-2 / 9)
    assert regulariser.edge_at(1.5) == pytest.approx(15.0)
    # as tuned (no reference) the field's scale changes nothing
    assert Regulariser(smoothness=1e-2, smoothness_edge=5.0).smoothness_at(0.0, 1.5) == 1e-2
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="relative_to"):
            Regulariser(smoothness=1e-2, relative_to=bad)


def test_a_field_s_rms_and_an_edge_that_follows_it_reuse_the_kernels():
    regulariser = Regulariser(smoothness=1e-2, smoothness_edge=5.0, relative_to=1e-3)
    field = make_field(FieldConfig(kind="grid", resolution=6), (0, 0, 0), (1, 1, 1), 1.0)
    field.assign({"grid": mi.TensorXf(np.full((6, 6, 6, 5), 2.0, dtype=np.float32))})
    assert field.rms() == pytest.approx(2.0)
    optimizer = dr.opt.Adam(lr=1e-2, params=field.parameters())

    def kernels_of_steps(steps):
        dr.kernel_history()
        for _ in range(steps):
            field.assign(optimizer)
            rms = field.rms()
            dr.backward(field.smoothness_penalty(regulariser.smoothness_at(0.0, rms), regulariser.edge_at(rms)))
            optimizer.step()
        dr.eval(optimizer["grid"])
        return {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}

    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        first = kernels_of_steps(2)
        assert kernels_of_steps(3) <= first


def test_a_decaying_smoothness_reuses_its_kernels():
    regulariser = Regulariser(smoothness=1e-2, final_smoothness=1e-4)
    field = make_field(FieldConfig(kind="grid", resolution=6), (0, 0, 0), (1, 1, 1), 1.0)
    optimizer = dr.opt.Adam(lr=1e-2, params=field.parameters())

    def kernels_of_steps(decays):
        dr.kernel_history()                     # clears it
        for decayed in decays:
            field.assign(optimizer)
            dr.backward(field.smoothness_penalty(regulariser.smoothness_at(decayed)))
            optimizer.step()
        dr.eval(optimizer["grid"])
        return {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}

    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        first = kernels_of_steps([0.0, 0.1])
        assert kernels_of_steps([0.4, 0.7, 1.0]) <= first


def test_refining_a_grid_keeps_a_linear_field():
    field = make_field(FieldConfig(kind="grid", resolution=3), (0, 0, 0), (2, 2, 2), 1.0)
    nodes = np.stack(np.meshgrid(*[np.linspace(0, 2, 3)] * 3, indexing="ij"), -1)      # x, y, z
    linear = (0.3 * nodes[..., 0] - 0.2 * nodes[..., 1] + 0.1 * nodes[..., 2]).transpose(2, 1, 0)
    field.assign({"grid": mi.TensorXf(np.repeat(linear[..., None], 5, -1).astype(np.float32))})
    finer = refined(field, 5)
    points = np.random.default_rng(1).uniform(0, 2, (40, 3))
    np.testing.assert_allclose(metrics.sample(finer, points), metrics.sample(field, points), atol=1e-5)


def test_stress_errors_are_relative_and_ignore_the_mean_stress():
    truth = UniformField(xx=3.0, yy=-1.0, xy=0.5, yz=0.2)
    points = np.zeros((4, 3))
    assert metrics.stress_errors(truth, truth, points).deviatoric == 0
    shifted = UniformField(xx=5.0, yy=1.0, zz=2.0, xy=0.5, yz=0.2)         # plus 2 MPa hydrostatic
    assert metrics.stress_errors(shifted, truth, points).deviatoric == pytest.approx(0, abs=1e-7)
    scaled = UniformField(xx=3.3, yy=-1.1, xy=0.55, yz=0.22)
    errors = metrics.stress_errors(scaled, truth, points)
    assert errors.deviatoric == pytest.approx(0.1, rel=1e-5)
    assert errors.principal_difference == pytest.approx(0.1, rel=1e-5)
    assert metrics.psnr(np.full(4, 0.5), np.full(4, 0.6)) == pytest.approx(20.0)
    with pytest.raises(ValueError, match="zero"):
        metrics.stress_errors(truth, UniformField(), points)


@pytest.mark.parametrize("z", [0.0, 2.9])
def test_points_inside_a_disk_are_found_on_a_lattice_through_its_triangle_fans(z):
    scene = mi_nest.load_scene("disk_compression", res=8)
    shapes = specimen_shapes(scene)
    x, y = np.meshgrid(*2 * [np.linspace(-20, 20, 97)])
    points = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], -1)
    radius = np.hypot(points[:, 0], points[:, 1])
    clear = np.abs(radius - 20) > 0.3       # the mesh is a polygon: leave its rim alone
    assert np.array_equal(occupancy.inside(scene, shapes, points)[clear], (radius < 20)[clear])


@pytest.mark.parametrize("resolution", [5, 9, 17])
def test_smoothness_is_the_mean_squared_gradient_at_every_resolution(resolution):
    """A field rising by ``slope`` across a cube: (slope / side)^2 along x, 0 along y and z, a third on average."""
    slope, weight = 2.0, 0.25
    field = make_field(FieldConfig(kind="grid", resolution=resolution), (0, 0, 0), (10, 10, 10), 1.0)
    _assign_ramp_along_x(field, slope)
    assert float(field.smoothness_penalty(weight)[0]) == pytest.approx(weight * slope ** 2 / 3, rel=1e-5)


def test_trilinear_basis_is_the_grid_fields_own_interpolation():
    field = make_field(FieldConfig(kind="grid", resolution=6), (-2, -1, 0), (4, 1, 3), 2.0)
    rng = np.random.default_rng(1)
    nx, ny, nz = field.shape
    nodes = rng.normal(size=(nz, ny, nx, 5)).astype(np.float32)
    field.assign({"grid": mi.TensorXf(nodes)})
    points = rng.uniform(field.bbox_min, field.bbox_max, (200, 3))
    basis = metrics.trilinear_basis(points, field.bbox_min, field.bbox_max, field.shape)
    sampled = stored_components(metrics.deviatoric_part(metrics.sample(field, points)), field.stress_scale)
    np.testing.assert_allclose(basis @ nodes.reshape(-1, 5), sampled, atol=2e-5)


def _disk_floor_case():
    """``(scene, shapes, truth, points, field)``: the 200 N disk over 4 mm, a 20-point lattice, an 8-node grid."""
    scene = mi_nest.load_scene("disk_compression", res=8, load=200, contact_width=4)
    shapes = specimen_shapes(scene)
    field = make_field(FieldConfig(kind="grid", resolution=8), *specimen_bounds(shapes), 1.0)
    return scene, shapes, shapes[0].interior_medium().field, metrics.evaluation_points(scene, shapes, 20), field


def test_the_best_fit_beats_nodal_sampling_and_fits_linear_fields_exactly():
    scene, shapes, truth, points, field = _disk_floor_case()
    sampled = metrics.representation_floor(field, truth, points)
    best = metrics.best_fit_floor(field, truth, scene, shapes, points, fit_points_per_axis=40)
    assert 0 < best < 0.8 * sampled
    bending = mi_nest.fields.BeamBendingField(width=6.0, height=40.0, moment=1e4)
    assert metrics.best_fit_floor(field, bending, scene, shapes, points, fit_points_per_axis=40) < 1e-4


def test_a_grid_with_more_nodes_than_evaluation_points_is_not_given_a_floor():
    """A grid at least as fine as the evaluation lattice fits the truth through every point: its floor of zero
    says nothing, and the summary says why instead of printing it."""
    from mi_nest.reconstruct import Reconstruction
    scene, shapes, truth, points, coarse = _disk_floor_case()
    fine = make_field(FieldConfig(kind="grid", resolution=48), *specimen_bounds(shapes), 1.0)
    floors = {name: metrics.grid_floor(field, truth, points) for name, field in (("coarse", coarse), ("fine", fine))}
    assert floors["fine"] < 1e-4 < 0.05 < floors["coarse"]
    assert metrics.floor_bounds_nothing(fine, floors["fine"], len(points))
    assert not metrics.floor_bounds_nothing(coarse, floors["coarse"], len(points))
    for field, floor, said in ((fine, floors["fine"], "they set no floor"),
                               (coarse, floors["coarse"], f"the best any grid of this size can score: "
                                                          f"{100 * floors['coarse']:.2f}%")):
        found = {"deviatoric_error": 0.3, "principal_difference_error": 0.3, "grid_floor": floor,
                 "evaluation_points": len(points)}
        assert said in Reconstruction(field, OptimizeConfig(), [], found, 0.0).describe()


def test_the_grid_floor_is_a_floor_no_grid_scores_below():
    scene, shapes, truth, points, field = _disk_floor_case()
    floor = metrics.grid_floor(field, truth, points)
    assert 0 < floor < metrics.best_fit_floor(field, truth, scene, shapes, points, fit_points_per_axis=40)
    assert floor < metrics.representation_floor(field, truth, points)
    nodes = metrics.fitted_nodes(field, truth, points)
    assert metrics._grid_error(field, nodes, truth, points) == pytest.approx(floor)
    rng = np.random.default_rng(3)
    for size in (1e-3, 1e-2, 1e-1):      # any grid nearby scores worse: the fit is the minimum
        assert metrics._grid_error(field, nodes + size * rng.standard_normal(nodes.shape), truth, points) > floor


def test_three_iterations_reduce_the_loss(tiny_dataset, tmp_path):
    scene = _scene()
    # At 8 x 8 pixels the load points' fringes alias: the run says so before it starts.
    assert mi_nest.Dataset(tiny_dataset).index["fringe_aliasing"]["views"] > 0
    with pytest.warns(RuntimeWarning, match=r"denser than the pixels .* in \d+ of 4 views.* three narrow bands"):
        result = optimize(scene, tiny_dataset, output=tmp_path / "run", progress=False, kind="grid",
                          track_error_every=1, **FAST)
    dataset = mi_nest.Dataset(tiny_dataset)
    start = make_field(result.field.config, result.field.bbox_min, result.field.bbox_max, result.field.stress_scale)
    tracer = Tracer(TracerConfig(step_size=1.0))
    assert dataset_loss(scene, dataset, result.field, tracer) < dataset_loss(scene, dataset, start, tracer)
    assert len(result.history) == 3 and np.isfinite(result.metrics["deviatoric_error"])
    # The error followed during the run ends where the final evaluation finds it.
    assert result.history[-1]["deviatoric_error"] == pytest.approx(result.metrics["deviatoric_error"], rel=1e-6)
    # The path curriculum spans the paths the specimen really has: a disk's from its thickness up.
    with np.load(tmp_path / "run" / "checkpoint.npz") as checkpoint:
        shortest, longest = json.loads(str(checkpoint["path_range"]))
    thickness, diameter = 6.0, 40.0
    assert 0.99 * thickness <= shortest < longest <= 1.01 * np.hypot(thickness, diameter)
    assert 0 < result.metrics["test_psnr"] < 100
    saved = json.loads((tmp_path / "run" / "reconstruction.json").read_text())
    assert saved["metrics"]["deviatoric_error"] == result.metrics["deviatoric_error"]
    # It says what it was reconstructed from, so that its views can find the scene again (issue 21).
    assert saved["source"]["dataset"] == str(Path(tiny_dataset).resolve())
    assert saved["source"]["scene"] == scene.id()
    assert saved["source"]["dataset_source"]["scene"] == mi_nest.Dataset(tiny_dataset).index["source"]["scene"]
    assert Reconstruction.load(tmp_path / "run").source == saved["source"]
    # The scene gets its own field back.
    assert type(scene.shapes()[0].interior_medium().field).__name__ == "DiskCompressionField"


# The finest stage (grid 6 after 4) starts at iteration 2 of 4; a 0.6 average takes iterations 2 and 3.
REGULARISED_AND_AVERAGED = {"smoothness": 1e-3, "final_smoothness": 1e-4, "smoothness_edge": 1.0,
                            "average_last": 0.6}


@pytest.mark.parametrize("extra", [{}, REGULARISED_AND_AVERAGED, {"equilibrium": 1e-2}],
                         ids=["plain", "averaged", "equilibrium"])
def test_an_interrupted_run_resumes_where_it_stopped(tiny_dataset, tmp_path, monkeypatch, extra):
    options = {**FAST, "iterations": 4, "checkpoint_every": 1, "kind": "grid", **extra}
    whole = optimize(_scene(), tiny_dataset, output=tmp_path / "whole", progress=False, **options)

    original = loop.Run.step

    def interrupted(self, integrator):
        if self.iteration == 3:
            raise KeyboardInterrupt
        return original(self, integrator)

    monkeypatch.setattr(loop.Run, "step", interrupted)
    with pytest.raises(KeyboardInterrupt):
        optimize(_scene(), tiny_dataset, output=tmp_path / "cut", progress=False, **options)
    monkeypatch.setattr(loop.Run, "step", original)
    resumed = optimize(_scene(), tiny_dataset, output=tmp_path / "cut", progress=False, **options)
    assert [h["iteration"] for h in resumed.history] == [0, 1, 2, 3]
    if "average_last" in extra:
        with np.load(tmp_path / "cut" / "checkpoint.npz") as checkpoint:
            assert int(checkpoint["iterates_averaged"]) == 2
    np.testing.assert_allclose(np.array(resumed.field.parameters()["grid"]), np.array(whole.field.parameters()["grid"]),
                               atol=1e-5)
    if "equilibrium" in extra:
        # the mean stress that balances the result is solved and kept with it
        assert np.abs(np.array(resumed.field.mean)).max() > 0
    with pytest.raises(ValueError, match="another run"):
        optimize(_scene(), tiny_dataset, output=tmp_path / "cut", progress=False, **{**options, "iterations": 5})


def test_the_result_is_the_mean_of_the_averaged_iterates(tiny_dataset, monkeypatch):
    original, iterates = loop.Run.step, []

    def recorded(self, integrator):
        loss = original(self, integrator)
        iterates.append(np.array(self.field.parameters()["grid"]))
        return loss

    monkeypatch.setattr(loop.Run, "step", recorded)
    result = optimize(_scene(), tiny_dataset, progress=False, **{**FAST, "iterations": 4, "kind": "grid",
                                                                    **REGULARISED_AND_AVERAGED})
    assert iterates[2].shape == iterates[3].shape != iterates[1].shape       # refined before iteration 2
    np.testing.assert_allclose(np.array(result.field.parameters()["grid"]), (iterates[2] + iterates[3]) / 2,
                               atol=1e-6)
    assert not np.allclose(iterates[2], iterates[3])
    with pytest.raises(ValueError, match="average_last"):
        OptimizeConfig(average_last=1.0)
    with pytest.raises(ValueError, match="smoothness_edge"):
        Regulariser(smoothness=1.0, smoothness_edge=-1.0)


def test_divergence_is_reported_with_the_last_good_checkpoint(tiny_dataset, tmp_path, monkeypatch):
    calls = []
    original = mi_nest.Dataset.ray_batch

    def corrupt_after_two(self, *args, **kwargs):
        positions, rows, columns, targets = original(self, *args, **kwargs)
        calls.append(1)
        if len(calls) > 2:
            targets = np.full_like(targets, np.nan)
        return positions, rows, columns, targets

    monkeypatch.setattr(mi_nest.Dataset, "ray_batch", corrupt_after_two)
    with pytest.raises(DivergenceError, match=r"iteration 2: the loss is nan; the last good checkpoint \(iteration 2\)"):
        optimize(_scene(), tiny_dataset, output=tmp_path / "run", progress=False,
                 **{**FAST, "iterations": 5, "checkpoint_every": 1, "kind": "grid"})
    assert (tmp_path / "run" / "checkpoint.npz").is_file()


def test_bad_options_and_mismatched_material_are_refused(tiny_dataset):
    with pytest.raises(ValueError, match="unknown option"):
        optimize(_scene(), tiny_dataset, progress=False, iteratons=3)
    with pytest.raises(ValueError, match="method"):
        optimize(_scene(), tiny_dataset, progress=False, method="rk4")
    with pytest.raises(ValueError, match="learning_rate"):
        optimize(_scene(), tiny_dataset, progress=False, learning_rate=-1.0)
    with pytest.raises(ValueError, match="track_error_every"):
        optimize(_scene(), tiny_dataset, progress=False, track_error_every=-1)
    with pytest.raises(ValueError, match="field kind"):
        optimize(_scene(), tiny_dataset, progress=False, kind="voxels")
    other = mi_nest.load_scene("disk_compression", res=8, fringe_value=20.0)
    with pytest.raises(ValueError, match="stress_optic_coefficient"):
        optimize(other, tiny_dataset, progress=False)
    with pytest.raises(mi_nest.SceneError, match="8x8"):
        optimize(mi_nest.load_scene("disk_compression", res=16), tiny_dataset, progress=False)


def test_cli_reconstructs_a_dataset(tiny_dataset, tmp_path, capsys):
    assert main(["reconstruct", str(tiny_dataset), "--allow-aliased",
                 "-o", str(tmp_path / "result"), "--iterations", "2",
                 "--option", "batch_size=64", "--resolution", "6", "--kind", "grid", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "relative deviatoric stress error" in out and "PSNR" in out
    # An 8-pixel disk under 200 N aliases in most of its pixels: reconstructed when asked, and marked.
    assert "UNRELIABLE: the dataset's fringes are denser than the pixels in 57%" in out
    assert (tmp_path / "result" / "field.npz").is_file()
    assert (tmp_path / "result" / "test_view.exr").is_file() and (tmp_path / "result" / "test_view.png").is_file()
    assert main(["reconstruct", str(tmp_path / "missing"), "-o", str(tmp_path / "x")]) == 2


def test_a_regulariser_given_is_kept_on_dense_fringes_even_where_it_equals_the_default(tiny_dataset):
    from mi_nest.reconstruct.config import DENSE_REGULARISED
    tiny = dict(iterations=1, batch_size=64, resolution=6, kind="grid", evaluate_views=1, pixel_samples=1)
    with pytest.warns(RuntimeWarning):
        by_default = optimize(_scene(), tiny_dataset, progress=False, **tiny)
        given = optimize(_scene(), tiny_dataset, progress=False, relative_to=REGULARISED.relative_to, **tiny)
    # 57% of the pixels alias: the default eases, the same value given is the user's.
    assert by_default.config.regulariser == DENSE_REGULARISED
    assert given.config.regulariser == REGULARISED


def test_a_dataset_too_aliased_to_resolve_is_refused_before_the_run_with_the_fix(tiny_dataset, tmp_path, capsys):
    assert main(["reconstruct", str(tiny_dataset), "-o", str(tmp_path / "result")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "fringes are denser than the pixels in 57% of the specimen's pixels" in error
    assert "less load" in error and "--res about" in error and "--allow-aliased" in error
    assert not (tmp_path / "result").exists()


def test_cli_reconstructs_for_a_number_of_minutes(tiny_dataset, tmp_path, capsys):
    timed = ["reconstruct", str(tiny_dataset), "--allow-aliased",
             "--option", "batch_size=64", "--resolution", "6", "--kind", "grid",
             "--no-progress", "--minutes"]
    assert main([*timed, "0.005", "-o", str(tmp_path / "result")]) == 0
    history = json.loads((tmp_path / "result" / "reconstruction.json").read_text())["history"]
    # The clock ended it, on the final learning rate.
    assert history[-1]["seconds"] >= 0.3
    assert history[-1]["learning_rate"] == pytest.approx(OptimizeConfig().optimiser.final_learning_rate, rel=0.05)
    assert main([*timed, "0", "-o", str(tmp_path / "x")]) == 2
    assert "--minutes must be a positive number of minutes, got 0" in capsys.readouterr().err


def test_cli_defaults_to_the_targets_regulariser_and_options_override_it(tiny_dataset, tmp_path, capsys):
    networks = ["reconstruct", str(tiny_dataset), "--allow-aliased", "--iterations", "2", "--option", "batch_size=64",
                "--no-progress"]
    common = [*networks, "--resolution", "6"]

    def config(name):
        return json.loads((tmp_path / name / "reconstruction.json").read_text())["config"]

    assert main([*common, "-o", str(tmp_path / "default")]) == 0
    assert config("default")["field"]["kind"] == "grid"
    # This dataset's fringes alias in more than 10% of its pixels: the targets' smoothness, eased for them.
    from mi_nest.reconstruct.config import DENSE_REGULARISED
    assert mi_nest.Dataset(tiny_dataset).index["fringe_aliasing"]["mean_fraction"] > 0.10
    assert Regulariser(**config("default")["regulariser"]) == DENSE_REGULARISED
    assert config("default")["optimiser"]["batch_size"] == 64
    assert main([*common, "--option", "smoothness=1e-3", "--option", "final-smoothness=none",
                 "-o", str(tmp_path / "grid")]) == 0
    assert config("grid")["regulariser"]["smoothness"] == 1e-3
    assert config("grid")["regulariser"]["smoothness_edge"] == REGULARISED.smoothness_edge
    assert config("grid")["regulariser"]["average_last"] == REGULARISED.average_last
    assert main([*common, "--no-regulariser", "-o", str(tmp_path / "plain")]) == 0
    assert Regulariser(**config("plain")["regulariser"]) == NO_REGULARISER
    # A network sampled on a lattice is smoothed there as a grid is; evaluated at every step it has no smoothness:
    # the default leaves it out, a smoothness asked for is refused.
    # (One lattice: the fit on each finer one is not what this checks, and takes half a minute on 2 cores.)
    assert main([*networks, "--kind", "mlp", "--option", "coarse_to_fine=false", "-o", str(tmp_path / "mlp")]) == 0
    assert Regulariser(**config("mlp")["regulariser"]) == DENSE_REGULARISED
    assert main([*networks, "--kind", "mlp", "--resolution", "0", "-o", str(tmp_path / "mlp_steps")]) == 0
    assert Regulariser(**config("mlp_steps")["regulariser"]) == NO_REGULARISER
    capsys.readouterr()
    assert main([*networks, "--kind", "mlp", "--resolution", "0", "--option", "smoothness=1e-3",
                 "-o", str(tmp_path / "refused")]) == 2
    assert "evaluated at every step (resolution=0): give a resolution" in capsys.readouterr().err
    # Another kind's options would be dropped without a word: they are refused, naming whose they are.
    assert main([*common, "--kind", "mlp", "--option", "levels=4", "-o", str(tmp_path / "refused")]) == 2
    assert ("a 'mlp' field does not read 'levels' (hashgrid's); leave it out, or give kind=hashgrid"
            in capsys.readouterr().err)
    for option, message in (("smoothnes=1", "unknown option 'smoothnes'; the options are average_last, "),
                            ("batch_size=6.5", "option 'batch_size' takes an integer, got '6.5'")):
        assert main([*common, "--option", option, "-o", str(tmp_path / "bad")]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err, err
    with pytest.raises(SystemExit) as usage:
        main([*common, "--option", "batch_size", "-o", str(tmp_path / "bad")])
    assert usage.value.code == 2 and "expected NAME=VALUE, got 'batch_size'" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_cli_fast_takes_the_fast_options_and_flags_override_them(tiny_dataset, tmp_path):
    from mi_nest.cli import _parser, _reconstruction_options
    from mi_nest.reconstruct import FAST_OPTIONS

    def options(*flags):
        return _reconstruction_options(_parser().parse_args(["reconstruct", "DATA", "-o", "OUT", *flags]))

    assert {k: options("--fast")[k] for k in FAST_OPTIONS} == FAST_OPTIONS
    assert OptimizeConfig(**FAST_OPTIONS).optimiser.coarse_pixel_samples == 1
    assert options("--fast", "--iterations", "7")["iterations"] == 7
    assert options("--fast", "--option", "batch_size=64")["batch_size"] == 64
    # The clock ends a timed run, not --fast's iteration count; the plain fit averages nothing.
    assert options("--fast", "--minutes", "2")["iterations"] == options("--minutes", "2")["iterations"] > 10 ** 6
    assert "average_last" not in options("--fast", "--no-regulariser")
    assert "batch_size" not in options()
    assert main(["reconstruct", str(tiny_dataset), "--allow-aliased",
                 "--fast", "--iterations", "2", "--option", "batch_size=64",
                 "--resolution", "6", "--no-progress", "-o", str(tmp_path / "fast")]) == 0
    record = json.loads((tmp_path / "fast" / "reconstruction.json").read_text())["config"]
    assert record["optimiser"]["coarse_pixel_samples"] == 1
    assert record["schedule"]["finest_stage"] == FAST_OPTIONS["finest_stage"]


def test_a_time_limit_stops_early_with_a_checkpoint(tiny_dataset, tmp_path):
    result = optimize(_scene(), tiny_dataset, output=tmp_path / "run", progress=False,
                      **{**FAST, "iterations": 10_000, "time_limit": 0.2, "kind": "grid", "track_error_every": 10_000})
    assert 1 <= len(result.history) < 10_000 and result.history[-1]["seconds"] >= 0.2
    # The error is followed at its interval and at the last step, wherever the clock stopped the run.
    assert "deviatoric_error" in result.history[0] and "deviatoric_error" in result.history[-1]
    assert (tmp_path / "run" / "checkpoint.npz").is_file()
    # The schedules follow the clock: the last learning rate is the final one.
    assert result.history[-1]["learning_rate"] == pytest.approx(OptimizeConfig().optimiser.final_learning_rate, rel=0.05)


def test_results_and_checkpoints_written_before_the_config_groups_still_load(tiny_dataset, tmp_path):
    """Before the configuration had groups, results recorded flat options, the field's (with the regulariser's
    smoothness) under "field", and the field's own state carried the smoothness too."""
    import json

    output = tmp_path / "run"
    result = optimize(_scene(), tiny_dataset, output=output, iterations=20, kind="grid", resolution=6,
                      smoothness=1e-4, checkpoint_every=10, progress=False)
    directory = result.save(tmp_path / "result")
    record = json.loads((directory / "reconstruction.json").read_text())
    groups = record["config"]
    flat = {k: v for name, group in groups.items() if name not in ("field", "regulariser") for k, v in group.items()}
    flat["average_last"] = groups["regulariser"]["average_last"]
    flat["field"] = {**groups["field"], **{k: v for k, v in groups["regulariser"].items() if k != "average_last"}}
    (directory / "reconstruction.json").write_text(json.dumps({**record, "config": flat}))

    def with_old_field_config(path, prefix=""):
        with np.load(path) as data:
            state = {key: data[key] for key in data.files}
        key = f"{prefix}config"
        state[key] = json.dumps({**json.loads(str(state[key])), "smoothness": 1e-4, "smoothness_edge": None})
        if prefix:
            state["config"] = json.dumps(flat)
        np.savez(path, **state)

    with_old_field_config(directory / "field.npz")
    loaded = Reconstruction.load(directory)
    assert loaded.config == result.config and loaded.config.regulariser.smoothness == 1e-4
    for key, value in result.field.state().items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(loaded.field.state()[key], value)
    # an old checkpoint of the same run resumes instead of being refused as another run's
    with_old_field_config(output / "checkpoint.npz", prefix="field.")
    resumed = optimize(_scene(), tiny_dataset, output=output, iterations=20, kind="grid", resolution=6,
                       smoothness=1e-4, checkpoint_every=10, progress=False)
    assert len(resumed.history) == 20


def test_a_relative_reference_without_a_grid_smoothness_reads_no_scale(tiny_dataset):
    """`relative_to` on an MLP (which has no smoothness and no rms) crashed the first iteration."""
    result = optimize(_scene(), tiny_dataset, iterations=2, kind="mlp", relative_to=1.0, batch_size=64,
                      coarse_to_fine=False, progress=False)
    assert len(result.history) == 2 and result.config.regulariser.relative_to == 1.0


@pytest.mark.parametrize("edge", [None, 0.7])
def test_the_smoothness_gradient_gathered_per_node_is_the_automatic_one(edge):
    from mi_nest.reconstruct.fields import _neighbour_pairs, _Smoothness
    shape, per_length, weight = (7, 5, 4), 8.0, 0.3
    values = np.random.default_rng(1).normal(size=int(np.prod(shape)) * 5).astype(np.float32)
    custom, automatic = mi.Float(values), mi.Float(values)
    dr.enable_grad(custom, automatic)
    first, second = _neighbour_pairs(shape)
    with dr.resume_grad():
        penalty = dr.custom(_Smoothness, custom, (first, second), shape, per_length, dr.opaque(mi.Float, weight),
                            None if edge is None else dr.opaque(mi.Float, edge ** 2))
        dr.backward(penalty)
        squared = dr.square((dr.gather(mi.Float, automatic, first) - dr.gather(mi.Float, automatic, second))
                            * per_length)
        plain = squared if edge is None else 2 * edge ** 2 * (dr.sqrt(1 + squared / edge ** 2) - 1)
        reference = weight * dr.mean(plain)
        dr.backward(reference)
    assert float(penalty[0]) == pytest.approx(float(reference[0]), rel=1e-5)
    np.testing.assert_allclose(np.array(dr.grad(custom)), np.array(dr.grad(automatic)), rtol=1e-4, atol=1e-7)
    assert np.abs(np.array(dr.grad(custom))).max() > 1e-3
