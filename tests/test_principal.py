"""Principal stresses and their directions (issue 21), and the exports that carry them: 3D-TSV's ``.TSV`` read
back by mi_nest's own importer, ParaView's ``.vtu`` with the directions as vectors."""
import math

import meshio
import numpy as np

import mi_nest
from mi_nest.cli import main
from mi_nest.fields import LameCylinderField
from mi_nest.io.tsv import read_stress_file
from mi_nest.physics.tensors import principal_axes, stress_matrices


def _six(matrix):
    m = np.asarray(matrix, dtype=np.float64)
    return np.array([m[0, 0], m[1, 1], m[2, 2], m[1, 2], m[2, 0], m[0, 1]])


def _same_line(a, b):
    """Directions are lines: equal up to sign."""
    np.testing.assert_allclose(abs(float(np.dot(a, b))), 1.0, atol=1e-9)


def test_uniaxial_stress_has_one_principal_stress_along_its_axis():
    axis = np.array([math.cos(0.5), math.sin(0.5), 0.3])
    axis /= np.linalg.norm(axis)
    values, directions = principal_axes(_six(5.0 * np.outer(axis, axis)))
    np.testing.assert_allclose(values, [5.0, 0.0, 0.0], atol=1e-12)
    _same_line(directions[0], axis)
    values, directions = principal_axes(_six(-5.0 * np.outer(axis, axis)))
    np.testing.assert_allclose(values, [0.0, 0.0, -5.0], atol=1e-12)
    _same_line(directions[2], axis)


def test_hydrostatic_pressure_plus_shear_turns_the_axes_45_degrees():
    p, tau = 2.0, 3.0
    values, directions = principal_axes(_six(p * np.eye(3) + tau * (np.outer([1, 0, 0], [0, 1, 0])
                                                                     + np.outer([0, 1, 0], [1, 0, 0]))))
    np.testing.assert_allclose(values, [p + tau, p, p - tau], atol=1e-12)
    np.testing.assert_allclose(directions, [[1 / math.sqrt(2), 1 / math.sqrt(2), 0], [0, 0, 1],
                                            [1 / math.sqrt(2), -1 / math.sqrt(2), 0]], atol=1e-12)
    # Orthonormal and right-handed up to the sign choice, whatever the tensor.
    tensors = np.random.default_rng(3).normal(size=(50, 6))
    values, directions = principal_axes(tensors)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", directions, directions),
                               np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-12)
    assert np.all(np.diff(values, axis=1) <= 0)
    rebuilt = np.einsum("nk,nki,nkj->nij", values, directions, directions)
    np.testing.assert_allclose(rebuilt, stress_matrices(tensors), atol=1e-12)


def test_a_lame_cylinders_principal_stresses_are_hoop_axial_and_radial():
    """Internal pressure: the hoop stress A + B / r^2 is the largest, along the tangent; the radial A - B / r^2
    the smallest (compressive), along the radius; open ends leave zero along the axis."""
    a, b, pressure = 10.0, 20.0, 8.0
    field = LameCylinderField(inner_radius=a, outer_radius=b, internal_pressure=pressure)
    radius, angle = np.full(12, 15.0), np.linspace(0, 2 * np.pi, 12, endpoint=False)
    points = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.linspace(-5, 5, 12)])
    stress = np.stack([np.asarray(c, dtype=np.float64) for c in field.eval(tuple(points))], axis=-1)
    values, directions = principal_axes(stress)
    big_a = pressure * a ** 2 / (b ** 2 - a ** 2)
    big_b = pressure * a ** 2 * b ** 2 / (b ** 2 - a ** 2)
    np.testing.assert_allclose(values, np.broadcast_to([big_a + big_b / 15.0 ** 2, 0.0, big_a - big_b / 15.0 ** 2],
                                                       (12, 3)), rtol=1e-5, atol=1e-5)
    for k in range(12):
        _same_line(directions[k, 0], [-math.sin(angle[k]), math.cos(angle[k]), 0.0])
        _same_line(directions[k, 1], [0.0, 0.0, 1.0])
        _same_line(directions[k, 2], [math.cos(angle[k]), math.sin(angle[k]), 0.0])


def test_a_scene_exported_as_tsv_reads_back_as_the_same_field_inside_the_specimen(tmp_path, capsys):
    """``mi-nest export SCENE -o field.TSV``: the grid's hexahedra inside the part, written in 3D-TSV's current
    format; mi_nest's own importer reads back the nodes and their stress as sampled."""
    output = tmp_path / "disk.TSV"
    main(["export", "disk_compression", "-o", str(output), "--resolution", "24", "-D", "load=100",
          "-D", "contact_width=4"])
    assert str(output.resolve()) in capsys.readouterr().out
    model = read_stress_file(output)
    assert open(output).read().startswith("Version 2.0\nStress Data Type: NODE\nSolid Hex 1\n")
    scene = mi_nest.load_scene("disk_compression", res=8, load=100, contact_width=4)
    medium = scene.shapes()[0].interior_medium()
    np.testing.assert_allclose(model.stress, medium.sample(model.vertices), rtol=1e-6, atol=1e-6)
    # Inside the disk (40 mm across, 6 thick): no node further from the axis than a cell's diagonal past it.
    radial = np.hypot(model.vertices[:, 0], model.vertices[:, 1])
    spacing = 40.0 / 23
    assert radial.max() <= 20.0 + math.sqrt(2) * spacing and model.elements.shape[1] == 8
    assert np.isin(np.arange(len(model.vertices)), model.elements).all()      # no stray nodes


def test_the_vtu_export_carries_the_principal_directions_as_vectors(tmp_path):
    output = tmp_path / "disk.vtu"
    main(["export", "disk_compression", "-o", str(output), "--resolution", "16", "-D", "load=100"])
    exported = meshio.read(output)
    stress = exported.point_data["stress"].reshape(-1, 3, 3)
    for k in range(3):
        direction = exported.point_data[f"sigma_{k + 1}_direction"]
        assert direction.shape == (len(exported.points), 3)
        np.testing.assert_allclose(np.einsum("nij,nj->ni", stress, direction),
                                   exported.point_data[f"sigma_{k + 1}"][:, None] * direction, atol=1e-4)


def test_an_export_to_an_unknown_format_is_refused_before_anything_is_loaded(tmp_path, capsys):
    assert main(["export", "disk_compression", "-o", str(tmp_path / "field.csv")]) == 2
    err = capsys.readouterr().err
    assert "unknown export format '.csv'; give a name ending in .vtu" in err and len(err.strip().splitlines()) == 1


def test_the_slice_plots_data_are_the_closed_forms():
    from mi_nest.fields import UniformField
    from mi_nest.views import Plane
    from mi_nest.views.principal import principal_slice
    # Lame's tube under internal pressure p, open ends: hoop, axial (zero) and radial stresses.
    scene = mi_nest.load_scene("lame_cylinder", res=16)
    data = principal_slice(scene, Plane.parse("z=1"), resolution=48)
    image = data.image
    points = image.centres().reshape(image.height, image.width, 3)
    r = np.hypot(points[..., 0], points[..., 1])
    a, b, p = 10.0, 20.0, 2.0
    k = p * a * a / (b * b - a * a)
    hoop, radial = k * (1 + b * b / r ** 2), k * (1 - b * b / r ** 2)
    inside = data.inside
    assert inside.sum() > 0.5 * np.pi * (b * b - a * a) / image.pixel ** 2
    np.testing.assert_allclose(data.values[..., 0][inside], hoop[inside], rtol=1e-4)
    np.testing.assert_allclose(data.values[..., 1][inside], 0.0, atol=1e-4)
    np.testing.assert_allclose(data.values[..., 2][inside], radial[inside], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(data.von_mises[inside], np.sqrt(hoop ** 2 - hoop * radial + radial ** 2)[inside],
                               rtol=1e-4)
    across, up = data.in_plane(0)       # the hoop direction is perpendicular to the radius
    radius = np.stack([points[..., 0], points[..., 1]], axis=-1) / r[..., None]
    np.testing.assert_allclose((across * radius[..., 0] + up * radius[..., 1])[inside], 0.0, atol=1e-4)
    assert np.isnan(data.values[~inside]).all()
    # Uniaxial stress, and hydrostatic pressure plus shear, as any field put in any part.
    axis = np.array([math.cos(0.5), math.sin(0.5), 0.0])
    uniaxial = _six(5.0 * np.outer(axis, axis))
    data = principal_slice(scene, Plane.parse("z=1"), 24, UniformField(*uniaxial))
    np.testing.assert_allclose(data.values[data.inside], [[5.0, 0.0, 0.0]] * int(data.inside.sum()), atol=1e-5)
    across, up = data.in_plane(0)
    np.testing.assert_allclose(np.abs(across * axis[0] + up * axis[1])[data.inside], 1.0, atol=1e-6)
    data = principal_slice(scene, Plane.parse("z=1"), 24, UniformField(xx=2, yy=2, zz=2, xy=3))
    np.testing.assert_allclose(data.values[data.inside], [[5.0, 2.0, -1.0]] * int(data.inside.sum()), atol=1e-5)
    deviator = principal_slice(scene, Plane.parse("z=1"), 24, UniformField(xx=2, yy=2, zz=2, xy=3), deviatoric=True)
    np.testing.assert_allclose(deviator.values[data.inside], [[3.0, 0.0, -3.0]] * int(data.inside.sum()), atol=1e-5)
    np.testing.assert_allclose(deviator.von_mises[data.inside], data.von_mises[data.inside])


def test_the_principal_command_plots_a_scene_and_refuses_a_plane_beside_it(tmp_path, capsys):
    output = tmp_path / "principal.png"
    assert main(["principal", "lame_cylinder", "--plane", "z=0", "--res", "32", "-o", str(output)]) == 0
    assert output.stat().st_size > 0 and "sigma_1 1.3" in capsys.readouterr().out
    assert main(["principal", "lame_cylinder", "--plane", "z=40", "-o", str(tmp_path / "x.png")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "misses the part" in error and not (tmp_path / "x.png").exists()
    assert main(["principal", "lame_cylinder", "--plane", "z=0", "--res", "0", "-o", str(tmp_path / "x.png")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "'resolution' must be an integer >= 2, got 0" in error
