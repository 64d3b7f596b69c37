"""Stress sources: closed-form equilibrium and boundary tractions, grid lookup, traverse()."""
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

import mi_nest
from mi_nest.fields import DiskCompressionField, TwistedField
from mi_nest.fields.grid import GridField
from mi_nest.io.grid import StressGrid, load_stress_grid, save_stress_grid
from scenes import box, medium, render


def divergence(field, points, h=1e-4):
    """div(sigma) by central differences, NumPy evaluation of the field."""
    def component(p, i, j):
        s = field.eval(tuple(p))
        index = {(0, 0): 0, (1, 1): 1, (2, 2): 2, (1, 2): 3, (2, 1): 3, (2, 0): 4, (0, 2): 4, (0, 1): 5, (1, 0): 5}
        return s[index[(i, j)]]
    result = []
    for i in range(3):
        total = 0.0
        for j in range(3):
            plus, minus = [points[k].copy() for k in range(3)], [points[k].copy() for k in range(3)]
            plus[j] = plus[j] + h
            minus[j] = minus[j] - h
            total = total + (component(plus, i, j) - component(minus, i, j)) / (2 * h)
        result.append(total)
    return result


def test_disk_field_is_in_equilibrium_with_traction_free_rim_and_frocht_centre():
    disk = DiskCompressionField(diameter=40, thickness=6, load=1000, axis=(0.2, 0.1, 1.0),
                                load_direction=(0.3, 1.0, 0.0), center=(1.0, -2.0, 0.5))
    rng = np.random.default_rng(3)
    e_x, e_y, axis = disk.frame
    r, a = 18 * np.sqrt(rng.uniform(0, 1, 200)), rng.uniform(0, 2 * np.pi, 200)
    points = [disk.center[k] + r * np.cos(a) * e_x[k] + r * np.sin(a) * e_y[k] for k in range(3)]
    div = divergence(disk, points)
    scale = 8 * 1000 / (math.pi * 40 * 6)
    assert max(np.max(np.abs(d)) for d in div) < 1e-4 * scale * 100   # MPa/mm, tiny vs stress/length
    # Traction-free rim away from the load points: sigma . n = 0.
    angles = np.concatenate([np.linspace(-0.5 * np.pi + 0.3, 0.5 * np.pi - 0.3, 20),
                             np.linspace(0.5 * np.pi + 0.3, 1.5 * np.pi - 0.3, 20)])
    s_x, s_y, t_xy = disk.plane_stress(20 * np.cos(angles), 20 * np.sin(angles))
    n = np.stack([np.cos(angles), np.sin(angles)])
    traction = np.stack([s_x * n[0] + t_xy * n[1], t_xy * n[0] + s_y * n[1]])
    assert np.max(np.abs(traction)) < 1e-6 * scale
    s_x, s_y, t_xy = disk.plane_stress(0.0, 0.0)
    assert s_x - s_y == pytest.approx(scale)
    assert s_y == pytest.approx(-6 * 1000 / (math.pi * 40 * 6))
    # The vertical section carries the load: integral of s_y over y = 0 equals -P/t.
    xs = np.linspace(-20, 20, 20001)
    assert np.trapezoid(disk.plane_stress(xs, 0 * xs)[1], xs) == pytest.approx(-1000 / 6, rel=1e-4)


def test_twisted_field_is_uniaxial_with_turning_axis():
    field = TwistedField(amplitude=2.0, rate=15.0, angle=10.0, axis=(0, 0, 1), origin=(0, 0, -1))
    s = field.eval((np.zeros(3), np.zeros(3), np.array([-1.0, 0.0, 5.0])))
    for i, depth in enumerate([0.0, 1.0, 6.0]):
        S = np.array([[s[0][i], s[5][i], s[4][i]], [s[5][i], s[1][i], s[3][i]], [s[4][i], s[3][i], s[2][i]]])
        values, vectors = np.linalg.eigh(S)
        assert values == pytest.approx([0, 0, 2.0], abs=1e-12)
        phi = math.radians(10 + 15 * depth)
        assert abs(vectors[:, 2] @ [math.cos(phi), math.sin(phi), 0]) == pytest.approx(1.0)


def sampled_grid(field, shape=(9, 7, 5), bbox_min=(-3, -2, -1), bbox_max=(3, 2, 4)):
    axes = [np.linspace(lo, hi, n) for lo, hi, n in zip(bbox_min, bbox_max, shape[::-1])]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    stress = np.stack(field.eval((x, y, z)), axis=-1).astype(np.float32)
    return StressGrid(stress, np.array(bbox_min, float), np.array(bbox_max, float)), axes


def test_grid_field_is_trilinear_on_nodes_and_matches_scipy(tmp_path):
    field = TwistedField(amplitude=3.0, rate=20.0, axis=(0.3, 0.2, 1.0))
    grid, axes = sampled_grid(field)
    save_stress_grid(tmp_path / "g.npz", grid)
    loaded = load_stress_grid(tmp_path / "g.npz")
    np.testing.assert_array_equal(loaded.stress, grid.stress)
    texture_field = GridField(loaded)
    rng = np.random.default_rng(0)
    points = np.stack([rng.uniform(lo, hi, 300) for lo, hi in zip(grid.bbox_min, grid.bbox_max)], axis=1)
    got = np.array(texture_field.eval(mi.Point3f(points.T.astype(np.float32))))
    for c in range(6):
        reference = RegularGridInterpolator((axes[2], axes[1], axes[0]), grid.stress[..., c])
        np.testing.assert_allclose(got[c], reference(points[:, ::-1]), atol=2e-5)


def test_grid_medium_renders_like_the_model_and_is_differentiable(tmp_path):
    twisted = dict(amplitude=0.6, rate=9.0, angle=30.0, origin=(0.0, 0.0, -10.0))
    grid, _ = sampled_grid(TwistedField(**twisted), shape=(161, 3, 3), bbox_min=(-20, -20, -10),
                           bbox_max=(20, 20, 10))
    save_stress_grid(tmp_path / "twisted.npz", grid)
    analytic = render([box((30, 30, 20), interior=medium("twisted", **twisted))], step=0.125)
    shapes = [box((30, 30, 20), interior={"type": "stress", "stress_optic_coefficient": 50.0,
                                           "filename": str(tmp_path / "twisted.npz")})]
    from scenes import scene
    gridded_scene = scene(shapes, step=0.125)
    gridded = mi_nest.render(gridded_scene).channels
    assert max(np.max(np.abs(analytic[n] - gridded[n])) for n in analytic) < 2e-3

    params = mi.traverse(gridded_scene)
    key = "specimen_0.interior_medium.stress"
    assert key in params and params.flags(key) & int(mi.ParamFlags.NonDifferentiable) == 0
    params[key] = params[key] * 0.0
    params.update()
    np.testing.assert_allclose(mi_nest.render(gridded_scene).channels["char.delta"], 0.0, atol=1e-6)


def test_projected_grid_equals_the_projected_texture_lookup_inside_and_outside():
    from mi_nest.fields.grid import ProjectedGrid
    from mi_nest.physics import projection
    disk = DiskCompressionField(diameter=8.0, thickness=4.0, load=50.0, contact_width=2.0)
    grid, _ = sampled_grid(disk, shape=(7, 9, 6), bbox_min=(-3, -2, -1), bbox_max=(3, 2, 4))
    field = GridField(grid)
    direction = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    u, v = projection.transverse_basis(tuple(-direction), (1.0, 0.2, 0.0))
    alpha, beta = projection.projection_coefficients(u, v)
    projected = ProjectedGrid(field, alpha, beta)
    rng = np.random.default_rng(3)
    points = np.stack([rng.uniform(lo - 1, hi + 1, 500) for lo, hi in zip(grid.bbox_min, grid.bbox_max)],
                      axis=1)
    p = mi.Point3f(points.T.astype(np.float32))
    expected = projection.apply_coefficients((alpha, beta), field.eval(p))
    for got, want in zip(projected.eval(p), expected):
        np.testing.assert_allclose(np.array(got), np.array(want), atol=2e-5 * np.abs(grid.stress).max())
    # A grid being differentiated keeps the texture's lookup, the one its gradients flow through.
    assert isinstance(field.projected(alpha, beta), ProjectedGrid)
    dr.enable_grad(field.texture.tensor())
    assert field.projected(alpha, beta) is None


@pytest.mark.filterwarnings("ignore:photoelastic. fringes denser")
@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_grid_renders_the_same_through_the_projected_lookup(tmp_path, monkeypatch, projection):
    """An orthographic camera's grid render looks up the view's projected two channels (ProjectedGrid); it
    must give the general six-channel lookup's image. A perspective camera's rays differ in frame: no
    projection."""
    from scenes import scene
    from mi_nest.tracer.setup import SceneSetup
    disk = DiskCompressionField(diameter=24.0, thickness=6.0, load=150.0, contact_width=4.0)
    grid, _ = sampled_grid(disk, shape=(12, 17, 15), bbox_min=(-10, -10, -3), bbox_max=(10, 10, 3))
    save_stress_grid(tmp_path / "disk.npz", grid)
    shapes = [box((20, 20, 6), interior={"type": "stress", "stress_optic_coefficient": 50.0,
                                         "filename": str(tmp_path / "disk.npz")})]
    options = dict(res=32, view=9.0, step=0.2, projection=projection, origin=(40.0, -30.0, 60.0),
                   up=(0.3, 1.0, 0.0), input_qwp=45.0, output_qwp=-45.0)
    used = []
    own = SceneSetup._projected_field
    monkeypatch.setattr(SceneSetup, "_projected_field", lambda *a: used.append(own(*a)) or used[-1])
    projected = mi_nest.render(scene(shapes, **options), spp=2, passes=2).channels
    # One per pass: the set-up that only decides the method builds none.
    assert len(used) == 2 and all((p is not None) == (projection == "orthographic") for p in used)
    monkeypatch.setattr(SceneSetup, "_projected_field", lambda *a: None)
    general = mi_nest.render(scene(shapes, **options), spp=2, passes=2).channels
    assert np.ptp(general["char.delta"]) > 1.0      # several fringes: the frames matter
    for name in general:
        np.testing.assert_allclose(projected[name], general[name], atol=2e-5, err_msg=name)


def test_saved_files_are_readable_like_normal_files(tmp_path):
    import os
    import stat
    from mi_nest.io.exr import write_channels
    from mi_nest.io.mesh import save_mesh_stress
    grid, _ = sampled_grid(TwistedField())
    save_stress_grid(tmp_path / "g.npz", grid)
    save_mesh_stress(tmp_path / "m.npz", np.zeros((4, 3)), [[0, 1, 2, 3]], np.zeros((4, 6)))
    write_channels(tmp_path / "c.exr", {"Y": np.zeros((2, 2))})
    umask = os.umask(0)
    os.umask(umask)
    for name in ("g.npz", "m.npz", "c.exr"):
        assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == 0o666 & ~umask, name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.exr", "g.npz", "m.npz"]   # no temp files left
