"""Issue 18, item 2, "Today's 3D-TSV files": .TSV / .TSVcarti with header lines, element-wise stress,
tet and hex solids, boundary conditions (kept, previewed, re-solved by mi-nest fem), malformed files."""
import math

import numpy as np
import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.fem import FemError, FemSpec, file_boundary_conditions, spec_from_flags
from mi_nest.fields.mesh import TetMeshStress
from mi_nest.fields.sources import grid_from_file, load_mesh, mesh_arrays
from mi_nest.io.carti import read_carti_file, write_carti_file
from mi_nest.io.cells import MeshError
from mi_nest.io.preview import mesh_preview_figure
from mi_nest.io.tsv import BoundaryConditions, TsvFileError, read_stress_file, write_stress_file
from scenes import BREWSTER, WAVELENGTH, scene
from test_specimens import KITTEN, hex_box, needs_kitten, uniaxial

KITTEN_TSV = KITTEN.with_suffix(".TSV")
needs_kitten_tsv = pytest.mark.skipif(not KITTEN_TSV.is_file(),
                                      reason="shared 3D-TSV sample kitten.TSV not beside the checkout")


def linear_stress(points):
    """A linear stress field: what per-element averaging must reproduce at symmetric interior nodes."""
    gradient = np.array([[1.0, -2.0, 0.5, 0.0, 3.0, -1.0], [0.5, 1.0, -1.0, 2.0, 0.0, 1.5],
                         [-1.0, 0.0, 2.0, 1.0, -0.5, 0.0]])
    return 10.0 + points @ gradient


def bar_with_its_load(tmp_path, force=1200.0, name="bar.TSV"):
    """A 40 x 10 x 10 mm hexahedral bar, fixed at x = 0, pulled at x = 40 by node forces that add up to
    ``force`` (N) and are consistent with a uniform traction; its stress as the exact uniaxial F / A."""
    nodes, hexes = hex_box(size=(40.0, 10.0, 10.0), cells=(16, 4, 4))
    end = np.flatnonzero(np.isclose(nodes[:, 0], 40.0))
    on_edge = np.isclose(nodes[end, 1], 0) | np.isclose(nodes[end, 1], 10)
    on_other_edge = np.isclose(nodes[end, 2], 0) | np.isclose(nodes[end, 2], 10)
    share = np.where(on_edge, 0.5, 1.0) * np.where(on_other_edge, 0.5, 1.0)
    forces = np.zeros((len(end), 4))
    forces[:, 0], forces[:, 1] = end, force * share / share.sum()
    fixed = np.flatnonzero(np.isclose(nodes[:, 0], 0.0))
    stress = np.zeros((len(nodes), 6))
    stress[:, 0] = force / 100.0
    path = tmp_path / name
    write_stress_file(path, nodes, hexes, stress, node_forces=forces, fixed_nodes=fixed)
    return path, nodes, forces, fixed


# --------------------------------------------------------------------------- reading every variant

@needs_kitten_tsv
@needs_kitten
def test_kitten_tsv_reads_as_the_early_stress_file_with_its_boundary_conditions():
    """Item 2: today's kitten.TSV (header lines, Node Forces / Fixed Nodes) is the same model as kitten.stress."""
    today, early = read_stress_file(KITTEN_TSV), read_stress_file(KITTEN)
    for name in ("vertices", "elements", "stress", "node_forces", "fixed_nodes"):
        np.testing.assert_array_equal(getattr(today, name), getattr(early, name), err_msg=name)
    mesh = load_mesh(KITTEN_TSV)
    np.testing.assert_array_equal(mesh.tets, load_mesh(KITTEN).tets)
    np.testing.assert_array_equal(mesh.stress, load_mesh(KITTEN).stress)
    conditions = mesh.boundary
    assert len(conditions.forces) == 96 and len(conditions.fixed_nodes) == 384
    for nodes in (conditions.force_nodes, conditions.fixed_nodes):
        assert nodes.min() >= 0 and nodes.max() < len(mesh.nodes)
    # The file's own story: the kitten stands on its fixed feet and is pushed down on its ears and back.
    np.testing.assert_allclose(conditions.total_force, [0.0, -1800.0, -96000.0])
    assert mesh.nodes[conditions.fixed_nodes, 2].max() < mesh.nodes[:, 2].min() + 2.0
    assert mesh.nodes[conditions.force_nodes, 2].min() > 50.0
    np.testing.assert_array_equal(grid_from_file(KITTEN_TSV, 12).stress, grid_from_file(KITTEN, 12).stress)


@pytest.mark.parametrize("name", ["part.TSV", "part.tsv", "part.Tsv", "part.stress"])
def test_header_lines_or_none_and_any_case_of_the_extension_give_the_same_model(tmp_path, name):
    """Item 2: a file with today's header lines and one without them load alike, under any case of .TSV."""
    nodes, hexes = hex_box(cells=(2, 2, 2))
    stress = linear_stress(nodes)
    write_stress_file(tmp_path / "reference.stress", nodes, hexes, stress, node_forces=[[3, 0.0, 0.0, -5.0]],
                      fixed_nodes=[0, 1])
    write_stress_file(tmp_path / name, nodes, hexes, stress, node_forces=[[3, 0.0, 0.0, -5.0]],
                      fixed_nodes=[0, 1])
    lines = (tmp_path / name).read_text().splitlines()
    assert (lines[0] == "Version 2.0") == name.lower().endswith(".tsv")
    headless = tmp_path / f"headless{(tmp_path / name).suffix}"
    headless.write_text("\n".join(line for line in lines if line.split()[0] not in ("Version", "Stress", "Solid"))
                        + "\n")
    reference = load_mesh(tmp_path / "reference.stress")
    for path in (tmp_path / name, headless):
        mesh = load_mesh(path)
        np.testing.assert_array_equal(mesh.tets, reference.tets)
        np.testing.assert_allclose(mesh.stress, reference.stress, rtol=1e-7)
        np.testing.assert_array_equal(mesh.boundary.fixed_nodes, [0, 1])
        np.testing.assert_array_equal(mesh.boundary.force_nodes, [3])
        np.testing.assert_allclose(grid_from_file(path, 8).stress, grid_from_file(tmp_path / "reference.stress",
                                                                                   8).stress, rtol=1e-6)


def test_element_stress_is_averaged_to_the_nodes_by_volume(tmp_path):
    """Item 2: 'Stress Data Type: ELEMENT' becomes nodal stress: a uniform field stays exactly uniform on
    uneven hexahedra and on tetrahedra, and a linear field sampled at the element centroids of an even grid
    comes back exactly at its interior nodes."""
    nodes, hexes = hex_box(size=(6.0, 5.0, 4.0), cells=(3, 3, 2))
    uneven = nodes.copy()
    uneven[:, 0] = uneven[:, 0] ** 1.3
    write_stress_file(tmp_path / "uniform.TSV", uneven, hexes, uniaxial(2.0, 30.0, len(hexes)))
    assert "Stress Data Type: ELEMENT" in (tmp_path / "uniform.TSV").read_text()
    uniform = read_stress_file(tmp_path / "uniform.TSV")
    assert uniform.element_stress and uniform.stress.shape == (len(nodes), 6)
    np.testing.assert_allclose(uniform.stress, uniaxial(2.0, 30.0, len(nodes)), atol=1e-12)
    # As a scene's specimen it renders the closed-form retarder of a uniform slab (seen along z).
    specimen = {"type": "specimen", "filename": str(tmp_path / "uniform.TSV"), "stress_optic_coefficient": BREWSTER,
                "grid_resolution": 8}
    channels = mi_nest.render(scene([specimen], res=4, view=2.0, origin=(3, 2.5, 100), target=(3, 2.5, 0),
                                    step=0.5)).channels
    np.testing.assert_allclose(channels["char.delta"], 2 * math.pi * BREWSTER * 4.0 * 2.0 / WAVELENGTH, atol=1e-4)
    np.testing.assert_allclose(channels["char.theta"], math.radians(30.0), atol=1e-4)

    tets = TetMeshStress.from_cells(uneven, hexes, np.zeros((len(nodes), 6))).tets
    write_stress_file(tmp_path / "tets.TSV", uneven, tets, uniaxial(-2.0, 75.0, len(tets)))
    np.testing.assert_allclose(load_mesh(tmp_path / "tets.TSV").stress, uniaxial(-2.0, 75.0, len(nodes)),
                               atol=1e-6)

    write_stress_file(tmp_path / "linear.TSV", nodes, hexes, linear_stress(nodes[hexes].mean(axis=1)))
    linear = read_stress_file(tmp_path / "linear.TSV")
    interior = np.all((nodes > nodes.min(axis=0)) & (nodes < nodes.max(axis=0)), axis=1)
    assert interior.sum() == 4
    np.testing.assert_allclose(linear.stress[interior], linear_stress(nodes[interior]), atol=1e-9)


def test_solid_tet_and_solid_hex_files(tmp_path):
    """Item 2: 'Solid Tet 1' and 'Solid Hex 1' files load as the same field; a header that contradicts
    the elements is refused on its line."""
    nodes, hexes = hex_box(cells=(2, 2, 1))
    tets = TetMeshStress.from_cells(nodes, hexes, np.zeros((len(nodes), 6))).tets
    stress = linear_stress(nodes)
    write_stress_file(tmp_path / "hex.TSV", nodes, hexes, stress)
    write_stress_file(tmp_path / "tet.TSV", nodes, tets, stress)
    assert "Solid Hex 1" in (tmp_path / "hex.TSV").read_text()
    assert "Solid Tet 1" in (tmp_path / "tet.TSV").read_text()
    points = np.random.default_rng(3).uniform([0, 0, 0], [10, 10, 4], size=(200, 3))
    np.testing.assert_allclose(load_mesh(tmp_path / "tet.TSV").sample(points),
                               load_mesh(tmp_path / "hex.TSV").sample(points), atol=1e-4)
    np.testing.assert_allclose(load_mesh(tmp_path / "tet.TSV").sample(points), linear_stress(points), atol=1e-4)
    wrong = (tmp_path / "tet.TSV").read_text().replace("Solid Tet 1", "Solid Hex 1")
    (tmp_path / "wrong.TSV").write_text(wrong)
    elements_line = 3 + 1 + len(nodes) + 1
    with pytest.raises(TsvFileError, match=rf"wrong.TSV:{elements_line}: elements have 4 nodes but line 3 announces "
                                           "hexahedra"):
        read_stress_file(tmp_path / "wrong.TSV")


def test_tsvcarti_is_one_based_and_loads_like_the_early_carti(tmp_path):
    """Item 2: today's .TSVcarti (CARTESIAN_GRID first, a stress data type line, one-based ids) gives the
    grid of the same early .carti (0-based ids); element-wise voxel stress averages to the nodes."""
    cells, lower, upper = (4, 3, 2), (0.0, 0.0, 0.0), (8.0, 6.0, 4.0)
    solid = np.array([0, 1, 2, 3, 4, 5, 7, 12, 13, 14, 15, 21])
    forces, fixed = [[0, 0.0, 0.0, -10.0]], [1, 2]
    write_carti_file(tmp_path / "early.carti", cells, lower, upper, solid, linear_stress, forces, fixed)
    write_carti_file(tmp_path / "today.TSVcarti", cells, lower, upper, solid, linear_stress, forces, fixed)
    text = (tmp_path / "today.TSVcarti").read_text().splitlines()
    assert text[:2] == ["DATASET CARTESIAN_GRID", "Stress Data Type: NODE"] and text[7].split()[0] == "1"
    early, today = read_carti_file(tmp_path / "early.carti"), read_carti_file(tmp_path / "today.TSVcarti")
    np.testing.assert_array_equal(today.voxels, early.voxels)
    np.testing.assert_array_equal(today.fixed_nodes, early.fixed_nodes)
    np.testing.assert_array_equal(today.node_forces, early.node_forces)
    np.testing.assert_allclose(today.stress, early.stress)
    np.testing.assert_allclose(grid_from_file(tmp_path / "today.TSVcarti").stress,
                               grid_from_file(tmp_path / "early.carti").stress)
    mesh = load_mesh(tmp_path / "today.TSVcarti")
    np.testing.assert_allclose(mesh.nodes[mesh.boundary.fixed_nodes], early.node_coordinates(np.array(fixed)))

    write_carti_file(tmp_path / "voxels.TSVcarti", cells, lower, upper, solid, lambda p: uniaxial(4.0, 10.0, len(p)),
                     element_stress=True)
    np.testing.assert_allclose(read_carti_file(tmp_path / "voxels.TSVcarti").stress,
                               uniaxial(4.0, 10.0, len(early.node_ids)), atol=1e-6)
    (tmp_path / "zero.TSVcarti").write_text("\n".join(text[:7] + ["0 " + text[7].partition(" ")[2]] + text[8:]))
    with pytest.raises(TsvFileError, match="one-based in .TSVcarti files; a file with 0-based ids is an early"):
        read_carti_file(tmp_path / "zero.TSVcarti")


# --------------------------------------------------------------------------- malformed files

def _malformed(lines, vertices):
    """(description, edit of the good .TSV's lines, message, line it must name) per bad-input class."""
    stress_header = next(i for i, line in enumerate(lines) if line.startswith("Cartesian Stress"))
    fixed_header = next(i for i, line in enumerate(lines) if line.startswith("Fixed Nodes"))
    element_header = next(i for i, line in enumerate(lines) if line.startswith("Elements"))

    def replaced(index, text):
        return lines[:index] + [text] + lines[index + 1:]
    return [
        ("truncated block", lines[:-2], "'Cartesian Stress' announces", stress_header + 1),
        ("count mismatch", replaced(stress_header, f"Cartesian Stress: {vertices - 1}")[:-1],
         f"{vertices - 1} stress rows for {vertices} vertices", stress_header + 1),
        ("too many rows", replaced(fixed_header, "Fixed Nodes: 1"),
         "a row of numbers where a section header was expected: does section 'Fixed Nodes'", fixed_header + 3),
        ("wrong column count", replaced(4, "1.0 2.0"), "section 'Vertices' rows must have 3 values, this one has 2", 5),
        ("unknown header", ["Version 2.0", "Units: mm"] + lines[1:], "expected a section header like 'Vertices: N' "
         "(3D-TSV header lines are", 2),
        ("unknown stress data type", replaced(1, "Stress Data Type: GAUSS"), "unknown stress data type 'GAUSS'", 2),
        ("second-order mesh", replaced(2, "Solid Hex 2"), "mi_nest reads first-order solids", 3),
        ("2D stress field", replaced(2, "Plane Quad 1"), "a 2D ('Plane') stress field", 3),
        ("NaN value", replaced(stress_header + 2, "nan 0 0 0 0 0"), "section 'Cartesian Stress' holds NaN or inf",
         stress_header + 3),
        ("fixed node out of range", replaced(fixed_header + 1, str(vertices + 1)),
         f"section 'Fixed Nodes' refers to node ids outside 1..{vertices}", fixed_header + 2),
        ("element node out of range", replaced(element_header + 1, "0 1 2 3 4 5 6 7"),
         f"section 'Elements' refers to node ids outside 1..{vertices}", element_header + 2),
    ]


def test_malformed_tsv_files_give_one_line_errors_naming_file_and_line(tmp_path, capsys):
    """Item 2: every malformed .TSV gets a one-line TsvFileError naming file and line; the CLI exits 2."""
    nodes, hexes = hex_box(cells=(2, 2, 1))
    good = tmp_path / "good.TSV"
    write_stress_file(good, nodes, hexes, uniaxial(1.0, 0.0, len(nodes)), node_forces=[[0, 1.0, 0.0, 0.0]],
                      fixed_nodes=[5, 6])
    lines = good.read_text().splitlines()
    for index, (what, edited, message, line) in enumerate(_malformed(lines, len(nodes))):
        path = tmp_path / f"bad{index}.TSV"
        path.write_text("\n".join(edited) + "\n")
        with pytest.raises(TsvFileError) as raised:
            read_stress_file(path)
        text = str(raised.value)
        assert "\n" not in text and message in text, (what, text)
        assert text.startswith(f"{path.resolve()}:{line}:"), (what, text)
        assert main(["export", str(path), "-o", str(tmp_path / "out.vtu")]) == 2, what
        error = capsys.readouterr().err
        assert error.count("\n") == 1 and error.startswith("mi-nest: error: ") and message in error, (what, error)
    assert not (tmp_path / "out.vtu").exists()


def test_boundary_conditions_are_checked_against_the_mesh():
    """Item 2: boundary conditions kept on a mesh must name its nodes and hold finite forces."""
    nodes, hexes = hex_box(cells=(1, 1, 1))
    stress = np.zeros((len(nodes), 6))
    with pytest.raises(MeshError, match=r"fixed nodes refer to nodes outside 0..7 \(got 2..8\)"):
        TetMeshStress.from_cells(nodes, hexes, stress, boundary=BoundaryConditions([], np.zeros((0, 3)), [2, 8]))
    with pytest.raises(ValueError, match="node forces hold NaN or inf"):
        BoundaryConditions([1], [[0.0, np.nan, 0.0]], [])
    kept = TetMeshStress.from_cells(nodes, hexes, stress, boundary=BoundaryConditions([1], [[0.0, 2.0, 0.0]], [0]))
    assert kept.boundary.describe() == "1 node forces (total (0, 2, 0) N), 1 fixed nodes"


# --------------------------------------------------------------------------- previews

def test_preview_draws_node_forces_as_arrows_and_fixed_nodes_as_markers(tmp_path, capsys):
    """Item 2: the mesh preview (mi-nest show FILE) draws each node force as an arrow ending at its node
    along the force, and each fixed node as a marker."""
    import matplotlib.image

    path, nodes, forces, fixed = bar_with_its_load(tmp_path)
    mesh = load_mesh(path)
    figure = mesh_preview_figure(mesh.nodes, mesh.surface, mesh.stress, mesh.boundary)
    axis = figure.axes[0]
    arrows = next(c for c in axis.collections if c.get_label() == f"node forces ({len(forces)})")
    markers = next(c for c in axis.collections if c.get_label() == f"fixed nodes ({len(fixed)})")
    shafts = np.asarray(arrows._segments3d)[:len(forces)]       # shafts first, then the two head lines each
    loaded = nodes[forces[:, 0].astype(int)]
    at_node = np.all(np.isclose(shafts, loaded[:, None], atol=1e-9), axis=2)
    assert np.all(at_node.sum(axis=1) == 1)                    # one end of each arrow at its node...
    direction = loaded - shafts[~at_node]                      # ...which the arrow points to
    np.testing.assert_allclose(direction[:, 1:], 0.0, atol=1e-9)
    assert np.all(direction[:, 0] > 0)
    np.testing.assert_allclose(direction[:, 0] / forces[:, 1], direction[0, 0] / forces[0, 1])
    assert len(markers._offsets3d[0]) == len(fixed)

    png = tmp_path / "bar.png"
    assert main(["show", str(path), "-o", str(png)]) == 0
    assert "25 node forces (total (1200, 0, 0) N), 25 fixed nodes" in capsys.readouterr().out
    image = matplotlib.image.imread(png)
    red = (image[..., 0] > 0.8) & (image[..., 1] < 0.3) & (image[..., 2] < 0.3)
    assert red.sum() > 50
    write_stress_file(tmp_path / "free.TSV", nodes, hex_box(size=(40.0, 10.0, 10.0), cells=(16, 4, 4))[1],
                      mesh.stress)
    assert main(["show", str(tmp_path / "free.TSV"), "-o", str(tmp_path / "free.png")]) == 0
    free = matplotlib.image.imread(tmp_path / "free.png")
    assert ((free[..., 0] > 0.8) & (free[..., 1] < 0.3) & (free[..., 2] < 0.3)).sum() == 0
    np.save(tmp_path / "grid.npy", np.zeros(3))
    assert main(["show", str(tmp_path / "grid.npy")]) == 2
    assert "mi-nest show takes a dataset directory or a mesh stress file" in capsys.readouterr().err


# --------------------------------------------------------------------------- mi-nest fem with the file's conditions

def test_fem_resolves_a_tsv_file_with_its_own_boundary_conditions(tmp_path, capsys):
    """Item 2: `mi-nest fem bar.TSV` re-solves the file's mesh with its fixed nodes and node forces: the
    reaction balances the file's load and the middle of the bar carries the file's F / A."""
    path, nodes, forces, fixed = bar_with_its_load(tmp_path)
    output = tmp_path / "bar.npz"
    assert main(["fem", str(path), "-o", str(output)]) == 0
    printed = capsys.readouterr().out
    assert "load 'node forces of bar.TSV': force (1200, 0, 0) N" in printed
    assert "fixture 'fixed nodes of bar.TSV': reaction (-1200, " in printed
    result = load_mesh(output)
    middle = np.isclose(result.nodes[:, 0], 20.0)
    file_stress = load_mesh(path).stress[0, 0]
    np.testing.assert_allclose(result.stress[middle, 0], file_stress, rtol=0.01)   # measured 0.25%
    assert np.abs(result.stress[middle][:, 1:]).max() < 0.005 * file_stress
    # Flags add to the file's conditions; a node the solver's mesh lacks is named.
    fixtures, loads = file_boundary_conditions(path)
    assert [len(f.where.points) for f in fixtures] == [len(fixed)] and len(loads[0].forces) == len(forces)
    spec = spec_from_flags(path, ["x=40:y"])
    assert [f.name for f in spec.fixtures] == ["fixed nodes of bar.TSV", "fix 1 (x=40:y)"]
    bad = FemSpec({"type": "file", "path": str(path)}, {"youngs_modulus": 3000.0, "poisson_ratio": 0.37},
                  fixtures=[{"name": "pins", "where": {"type": "nodes", "points": [[0.0, 0.0, 0.0], [0.0, 5.5, 0.0]]}}],
                  loads=[{"name": "pull", "type": "node_forces", "where": {"type": "nodes", "points": [[40, 5, 5]]},
                          "forces": [[100.0, 0.0, 0.0]]}])
    with pytest.raises(FemError, match=r"fixture 'pins': no mesh node at \(0, 5.5, 0\) \(the nearest is 0.5 mm"):
        bad.run()
    with pytest.raises(FemError, match="2 forces for 1 nodes: give one per node"):
        FemSpec({"type": "box", "size": [1, 1, 1]}, {"youngs_modulus": 1.0, "poisson_ratio": 0.3}, fixtures=[],
                loads=[{"name": "p", "type": "node_forces", "where": {"type": "nodes", "points": [[0, 0, 0]]},
                        "forces": [[1, 0, 0], [0, 1, 0]]}])


@needs_kitten_tsv
def test_fem_resolves_the_kitten_with_its_own_boundary_conditions():
    """Item 2: re-solving kitten.TSV's mesh (hexahedra in six P1 tetrahedra) with its 384 fixed nodes and
    96 node forces gives the file's stress: measured correlation 0.947 over all components (von Mises
    0.978), relative Frobenius difference 0.32 (the hexahedral original is softer at the point loads)."""
    result = spec_from_flags(KITTEN_TSV, []).run()
    reference = load_mesh(KITTEN_TSV)
    np.testing.assert_array_equal(result.field.nodes, reference.nodes)   # no node is unused, so none renumbered
    ours, theirs = result.field.stress.astype(np.float64), reference.stress.astype(np.float64)
    np.testing.assert_allclose(result.report.reactions["fixed nodes of kitten.TSV"], [0.0, 1800.0, 96000.0],
                               atol=1e-3)
    correlation = np.corrcoef(ours.ravel(), theirs.ravel())[0, 1]
    from mi_nest.physics.tensors import von_mises
    von_mises_correlation = np.corrcoef(von_mises(ours), von_mises(theirs))[0, 1]
    difference = np.linalg.norm(ours - theirs) / np.linalg.norm(theirs)
    assert correlation > 0.93 and von_mises_correlation > 0.96 and difference < 0.35, \
        (correlation, von_mises_correlation, difference)
    assert mesh_arrays(KITTEN_TSV)[1].shape == (14410, 8)
