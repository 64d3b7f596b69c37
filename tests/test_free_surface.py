"""The free-surface prior: the deviator's shear traction on the part's free surface (zero in equilibrium)."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mi_nest
from mi_nest.fields.analytic import UniformField
from mi_nest.reconstruct import FieldConfig, OptimizeConfig, metrics
from mi_nest.reconstruct.fields import DeviatoricGrid
from mi_nest.reconstruct.free_surface import FreeSurfacePrior
from mi_nest.scene import specimen_bounds, specimen_media, specimen_shapes


@pytest.fixture(scope="module")
def disk():
    scene = mi_nest.load_scene("disk_compression", contact_width="4", load="300")
    return scene, FreeSurfacePrior(scene, 40 / 64)


def _grid(scene, field, resolution=32):
    shapes = specimen_shapes(scene)
    grid = DeviatoricGrid(FieldConfig(kind="grid", resolution=resolution), *specimen_bounds(shapes), 1.0)
    grid.set_nodes(metrics.fitted_nodes(grid, field, metrics.evaluation_points(scene, shapes, 72)))
    return grid


class _Sum:
    def __init__(self, *fields):
        self.fields = fields

    def eval(self, p):
        values = [f.eval(p) for f in self.fields]
        return tuple(sum(v[k] for v in values) for k in range(6))


def test_the_prior_is_nearly_zero_in_equilibrium_and_not_on_a_planted_shear(disk):
    scene, prior = disk
    truth = specimen_media(scene)[0].field
    balanced = float(prior.penalty(_grid(scene, truth), 1.0, np.random.default_rng(0))[0])
    # A uniform shear in the disk's faces' normal direction: traction on its free faces, and not in equilibrium
    # with them, at a tenth of the field's RMS stress.
    planted = float(prior.penalty(_grid(scene, _Sum(truth, UniformField(zx=0.1 * 0.8))), 1.0,
                                  np.random.default_rng(0))[0])
    assert balanced < 1e-3
    assert planted > 10 * balanced


def test_the_prior_s_gradient_is_its_finite_differences(disk):
    scene, prior = disk
    grid = _grid(scene, specimen_media(scene)[0].field, resolution=12)
    nodes = grid.nodes() + np.random.default_rng(3).normal(scale=0.2, size=grid.nodes().shape).astype(np.float32)

    def penalty(values, grad=False):
        tensor = mi.TensorXf(values.reshape(*grid.shape[::-1], 5))
        if grad:
            dr.enable_grad(tensor)
        grid.assign({"grid": tensor})
        value = prior.penalty(grid, 0.7, np.random.default_rng(5))
        if grad:
            dr.backward(value)
            return float(value[0]), np.array(dr.grad(tensor)).reshape(-1, 5)
        return float(value[0])

    _, gradient = penalty(nodes, grad=True)
    step = 1e-2
    touched = np.flatnonzero(np.abs(gradient).sum(axis=1) > 1e-3 * np.abs(gradient).max())
    for node in np.random.default_rng(4).choice(touched, 6, replace=False):
        for channel in (0, 4):
            up, down = nodes.copy(), nodes.copy()
            up[node, channel] += step
            down[node, channel] -= step
            expected = (penalty(up) - penalty(down)) / (2 * step)
            tolerance = 2e-4 * float(np.abs(gradient).max())
            assert gradient[node, channel] == pytest.approx(expected, rel=2e-2, abs=tolerance)


def test_a_reconstruction_takes_the_prior_and_refuses_a_negative_weight(tmp_path):
    from mi_nest.dataset import simulate
    from scenes import TINY
    simulate("disk_compression", tmp_path / "data", TINY, progress=False, defines={"load": 20})
    scene = mi_nest.load_scene("disk_compression", res=8, load=20)
    prior = FreeSurfacePrior(scene, 40 / 64)
    shear = {}
    for weight in (0.0, 30.0):
        result = mi_nest.optimize(scene, mi_nest.Dataset(tmp_path / "data"), progress=False, iterations=40,
                                  resolution=8, free_surface=weight)
        assert result.field.rms() > 0.01            # the rays' gradients still move the field
        shear[weight] = float(prior.penalty(result.field, 1.0, np.random.default_rng(0))[0])
    assert shear[30.0] < 0.5 * shear[0.0]
    with pytest.raises(ValueError, match="free_surface must be a non-negative weight"):
        OptimizeConfig(free_surface=-1.0)
