"""Your own part, end to end (docs/specimens.md): the shipped meshed part with named surfaces, its spec file and
scene template, through fem, render, simulate, reconstruct and principal on the real command line."""
import importlib.util
import json
import re

import meshio
import numpy as np
import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.fem import read_volume_mesh
from mi_nest.fields.sources import load_mesh
from mi_nest.io.exr import read_channels
from mi_nest.physics.tensors import von_mises

EXAMPLES = mi_nest.scene_path("disk_compression").parent / "examples"
PART = EXAMPLES / "block_with_hole.msh"
SPEC = EXAMPLES / "block_with_hole.toml"
SCENE = EXAMPLES / "part.xml"
SCRIPT = EXAMPLES.parents[1] / "scripts" / "make_example_part.py"
LOAD = 500.0                        # N down on the top face, as the docs' walk
SIDE, THICKNESS, HOLE_RADIUS = 30.0, 8.0, 5.0
VIEW_WIDTH = 44.0                   # mm: part.xml's default view, a half-width of 22


def _printed_vector(text, label):
    """The (x, y, z) a fem report prints after ``label``, e.g. ``fixture 'base': reaction (0, 500, 0) N``."""
    found = re.search(re.escape(label) + r" \(([^)]*)\) N", text)
    assert found, f"no '{label}' in:\n{text}"
    return np.array([float(v) for v in found.group(1).split(",")])


def test_the_script_makes_the_shipped_part_with_the_named_surfaces_the_docs_use(tmp_path):
    spec = importlib.util.spec_from_file_location("make_example_part", SCRIPT)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    made = script.main(tmp_path)
    assert made.read_bytes() == PART.read_bytes()
    assert PART.stat().st_size < 200_000
    mesh = read_volume_mesh(PART)
    assert sorted(mesh.boundaries) == ["base", "hole", "top"]
    # Each group is the whole face it names: areas 30 x 8 for base and top, 2 pi r t (less the polygon's) for the bore.
    for name, area in (("base", SIDE * THICKNESS), ("top", SIDE * THICKNESS),
                       ("hole", 2 * np.pi * HOLE_RADIUS * THICKNESS)):
        corners = mesh.p[:, mesh.facets[:, mesh.boundaries[name]]]
        found = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], axis=0),
                                     axis=0).sum()
        np.testing.assert_allclose(found, area, rtol=0.01, err_msg=name)


def test_a_mesh_without_the_named_surface_says_what_it_has_and_how_to_select_faces(tmp_path, capsys):
    plain = tmp_path / "plain.vtu"
    part = meshio.read(PART)
    meshio.write(plain, meshio.Mesh(part.points, [part.cells[0]]))         # the tetrahedra, no names
    assert main(["fem", str(plain), "--fix", "base", "--load", "top:0,-500,0", "-o", str(tmp_path / "p.npz")]) == 2
    error = capsys.readouterr().err
    assert len(error.strip().splitlines()) == 1
    assert "no surface group 'base'; it has none" in error
    assert "gmsh physical surfaces in .msh" in error and "x=<v>, y=<v> or z=<v>" in error
    assert "the mesh spans x -15 to 15, y -15 to 15, z -4 to 4 mm" in error
    # The planes the message points to select the same faces as the shipped part's names.
    assert main(["fem", str(plain), "--fix", "y=-15", "--load", "y=15:0,-500,0", "-o", str(tmp_path / "p.npz")]) == 0
    assert main(["fem", str(PART), "--fix", "base", "--load", "top:0,-500,0", "-o", str(tmp_path / "n.npz")]) == 0
    np.testing.assert_array_equal(load_mesh(tmp_path / "p.npz").stress, load_mesh(tmp_path / "n.npz").stress)
    assert main(["fem", str(PART), "--fix", "bottom", "--load", "top:0,-500,0", "-o", str(tmp_path / "p.npz")]) == 2
    assert "no surface group 'bottom'; it has ['base', 'hole', 'top']" in capsys.readouterr().err


# 24 pixels across a part with five fringes at its hole: the render says they alias, as it should.
@pytest.mark.filterwarnings("ignore:photoelastic. fringes denser than the pixel grid")
def test_your_own_part_end_to_end(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)                     # relative paths, as the docs' commands use them

    assert main(["fem", str(PART), "--fix", "base", "--load", f"top:0,-{LOAD:g},0", "-o", "part.npz"]) == 0
    report = capsys.readouterr().out
    applied = _printed_vector(report, f"load 'load 1 (top:0,-{LOAD:g},0)': force")
    reaction = _printed_vector(report, "fixture 'fix 1 (base)': reaction")
    np.testing.assert_allclose(applied, [0.0, -LOAD, 0.0], atol=1e-9)
    np.testing.assert_allclose(reaction + applied, 0.0, atol=1e-3 * LOAD)     # the base holds what the top takes
    field = load_mesh("part.npz")
    equivalent = von_mises(field.stress)
    peak = field.nodes[np.argmax(equivalent)]
    # The hole concentrates the stress at its sides, well above the net section's 500 N / (20 x 8) mm^2.
    np.testing.assert_allclose(np.hypot(peak[0], peak[1]), HOLE_RADIUS, atol=1e-6)
    assert abs(peak[0]) > 4.0 and equivalent.max() > 1.5 * LOAD / ((SIDE - 2 * HOLE_RADIUS) * THICKNESS)

    assert main(["fem", "--spec", str(SPEC), "-o", "spec.npz"]) == 0       # the same model as a spec file
    np.testing.assert_array_equal(load_mesh("spec.npz").stress, field.stress)

    assert main(["render", str(SCENE), "-D", "part=part.npz", "-D", "res=24", "-o", "part.exr", "--png", "part.png",
                 "--quiet"]) == 0
    channels = read_channels("part.exr", ["char.delta", "path.length"])
    inside = channels["path.length"] > 0
    # Straight through 8 mm wherever the block, less its hole, covers the view.
    np.testing.assert_allclose(channels["path.length"].mean() / THICKNESS,
                               (SIDE ** 2 - np.pi * HOLE_RADIUS ** 2) / VIEW_WIDTH ** 2, atol=0.01)
    assert (tmp_path / "part.png").is_file()
    assert np.all(channels["char.delta"][~inside] == 0.0) and np.median(channels["char.delta"][inside]) > 0.5

    assert main(["simulate", str(SCENE), "-D", "part=part.npz", "-D", "fringe_value=53", "-o", "data",
                 "--azimuth", "2", "--elevation", "2", "--res", "16"]) == 0
    index = json.loads((tmp_path / "data" / "dataset.json").read_text())
    assert len(index["rotations"]) == 4 and len(list((tmp_path / "data" / "rotations").glob("*.exr"))) == 4

    assert main(["reconstruct", "data", "-o", "results", "--iterations", "20", "--resolution", "8",
                 "--no-progress"]) == 0
    assert "relative deviatoric stress error" in capsys.readouterr().out
    assert (tmp_path / "results" / "field.npz").is_file() and (tmp_path / "results" / "reconstruction.json").is_file()

    assert main(["principal", "results", "--plane", "z=0", "--res", "32", "-o", "principal.png"]) == 0
    printed = capsys.readouterr().out
    assert "von Mises against the truth" in printed and (tmp_path / "principal.png").is_file()


@pytest.mark.parametrize("order", [1, 2])
def test_a_fem_result_carries_its_loads_and_fixtures_into_3d_tsv_and_solves_again_the_same(order, tmp_path):
    """``fem`` -> ``export .TSV`` -> ``fem`` of that file: the node forces add up to the applied load (a P2
    model's edge forces shared by the edges' ends), the fixed nodes are the clamped face's, and a P1 model solved
    again from the 3D-TSV file has the same stress."""
    from mi_nest.io.tsv import read_stress_file
    first, again, exported = tmp_path / "part.npz", tmp_path / "again.npz", tmp_path / "part.TSV"
    assert main(["fem", str(EXAMPLES / "block_with_hole.msh"), "--fix", "base", "--load", "top:0,-500,0",
                 "--order", str(order), "-o", str(first)]) == 0
    assert main(["export", str(first), "-o", str(exported)]) == 0
    model = read_stress_file(exported)
    np.testing.assert_allclose(model.node_forces[:, 1:].sum(axis=0), [0.0, -500.0, 0.0], atol=1e-9)
    assert np.allclose(model.vertices[model.fixed_nodes, 1], -15.0) and len(model.fixed_nodes) > 10
    assert np.allclose(model.vertices[model.node_forces[:, 0].astype(int), 1], 15.0)
    if order == 1:
        assert main(["fem", str(exported), "-o", str(again)]) == 0
        with np.load(first) as a, np.load(again) as b:
            np.testing.assert_allclose(b["stress"], a["stress"], atol=1e-5 * np.abs(a["stress"]).max())
