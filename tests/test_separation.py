"""The full stress tensor: the mean stress separated from the deviator by equilibrium (mi_nest.separation).

Checks against exact equilibrium fields (a uniaxial bar, pure bending, Lame's tube, Frocht's disk,
Boussinesq's half-space), whose mean stress is known: the separation sees only their deviator.
"""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scenes import TINY, box, medium, scene

import mi_nest
from mi_nest.cli import main
from mi_nest.dataset import simulate
from mi_nest.fields import StressField
from mi_nest.fields.base import sample
from mi_nest.io.exr import read_channels
from mi_nest.io.grid import StressGrid, load_stress_grid
from mi_nest.fields.grid import GridField
from mi_nest.separation import RegionError, SeparationError, parse_region, separate
from mi_nest.separation.report import inside_nodes
from mi_nest.scene import specimen_media


def _mean_error(separation, truth: StressField, keep=None) -> float:
    """RMS error of the separated mean stress at the lattice's inside nodes (``keep``: a mask of them), per the
    truth's RMS stress there."""
    points = inside_nodes(separation)
    true = sample(truth, points)
    found = separation.mean[separation.inside]
    keep = np.ones(len(points), dtype=bool) if keep is None else keep
    scale = np.sqrt(np.mean(np.sum(true[keep, :3] ** 2, 1) + 2 * np.sum(true[keep, 3:] ** 2, 1)))
    return float(np.sqrt(np.mean((found[keep] - true[keep, :3].mean(1)) ** 2)) / scale)


def _model(scene_):
    return specimen_media(scene_)[0].field


def _away(separation, centres, distance) -> np.ndarray:
    return cKDTree(np.asarray(centres, dtype=float)).query(inside_nodes(separation))[0] > distance


def test_a_uniaxial_bar_has_a_third_of_its_stress_as_mean():
    bar = scene([box((30, 5, 5), interior=medium("uniform", xx=6.0))])
    separation = separate(None, bar, resolution=24)
    # The end faces are loaded, and the sides within two lattice spacings of them (the regions' margin).
    spacing = separation.summary["spacing_mm"]
    free_area = 4 * 5 * (30 - 2 * 2 * spacing)
    assert separation.summary["loaded"]["free_share"] == pytest.approx(free_area / (4 * 30 * 5 + 2 * 25), abs=0.02)
    assert np.allclose(separation.mean[separation.inside], 2.0, atol=1e-6)
    full = separation.field_values(inside_nodes(separation))
    assert np.allclose(full, [6, 0, 0, 0, 0, 0], atol=1e-5)        # the whole tensor back, sigma_yy = sigma_zz = 0


def test_pure_bending_mean_stress_is_linear_across_the_beam():
    beam = mi_nest.load_scene("beam_bending")
    separation = separate(None, beam, resolution=32)
    assert _mean_error(separation, _model(beam)) < 1e-3


def test_lame_tube_mean_stress_within_a_percent():
    tube = mi_nest.load_scene("lame_cylinder")
    separation = separate(None, tube, resolution=32)
    assert separation.summary["loaded"]["by_model"] > 0.15          # the bore carries the pressure
    assert _mean_error(separation, _model(tube)) < 0.01


def test_frocht_disk_is_plane_stress_away_from_its_contacts():
    disk = mi_nest.load_scene("disk_compression", contact_width="4", load="100")
    separation = separate(None, disk, resolution=48)
    away = _away(separation, [(0, 20, 0), (0, -20, 0)], 4.0)          # a tenth of the diameter
    assert _mean_error(separation, _model(disk), away) < 0.01
    full = separation.field_values(inside_nodes(separation))[away]
    true = sample(_model(disk), inside_nodes(separation)[away])
    scale = np.sqrt(np.mean(np.sum(true[:, :3] ** 2, 1) + 2 * np.sum(true[:, 3:] ** 2, 1)))
    assert np.sqrt(np.mean(full[:, 2] ** 2)) < 0.01 * scale          # sigma_zz = 0, found from the deviator alone


def test_boussinesq_half_space_away_from_the_point_load():
    half_space = mi_nest.load_scene("boussinesq")
    separation = separate(None, half_space, resolution=48)
    assert separation.summary["loaded"]["free_share"] < 0.2          # the cut faces carry the half-space's traction
    away = _away(separation, [(0, 0, 0)], 8.0)
    assert _mean_error(separation, _model(half_space), away) < 0.01


def test_a_faceted_free_surface_is_not_read_as_loaded():
    # The shaft's cylinder is a polygon: its facets tilt the normal by up to a few degrees, and the shear on them
    # reads as a few % of traction; only its end faces are loaded. Its mean stress is zero.
    shaft = mi_nest.load_scene("shaft_torsion")
    separation = separate(None, shaft, resolution=32)
    assert 0.7 < separation.summary["loaded"]["free_share"] < 0.9
    scale = np.sqrt(np.mean(np.sum(separation.grid.stress[separation.inside][:, 3:] ** 2, axis=1) * 2))
    assert np.abs(separation.mean[separation.inside]).max() < 1e-3 * scale


def test_an_fem_file_that_records_no_loads_gives_none():
    bracket = mi_nest.load_scene("bracket")
    separation = separate(None, bracket, resolution=24)
    assert separation.summary["loaded"]["by_model"] == 0.0
    assert separation.summary["suspect_loads"]          # its clamp and tip carry traction: reported


def test_the_fields_trace_is_ignored():
    tube = mi_nest.load_scene("lame_cylinder")
    exact = separate(None, tube, resolution=24)
    grid = exact.grid
    shifted = grid.stress.copy()
    shifted[..., :3] += 7.0
    moved = separate(GridField(StressGrid(shifted, grid.bbox_min, grid.bbox_max)), tube)
    assert moved.summary["own_grid"]
    assert np.allclose(moved.mean[moved.inside], exact.mean[exact.inside], atol=1e-4 * np.abs(exact.mean).max())


def test_noise_in_the_deviator_gives_a_bounded_error_in_the_mean():
    tube = mi_nest.load_scene("lame_cylinder")
    exact = separate(None, tube, resolution=32)
    rng = np.random.default_rng(0)
    grid = exact.grid
    errors = []
    for share in (0.02, 0.08):
        noisy = grid.stress.copy()
        scale = np.sqrt(np.mean(noisy[exact.inside] ** 2))
        noisy += share * scale * rng.normal(size=noisy.shape).astype(np.float32)
        separation = separate(GridField(StressGrid(noisy, grid.bbox_min, grid.bbox_max)), tube)
        errors.append(_mean_error(separation, _model(tube)))
    # White noise of 2% and 8% per node: the mean stress error grows with it and stays below the noise itself.
    assert errors[0] < errors[1] < 0.08
    assert errors[0] < 0.02


def test_a_missing_contact_is_reported_not_absorbed():
    disk = mi_nest.load_scene("disk_compression", contact_width="4", load="100")
    assert separate(None, disk, resolution=32).summary["suspect_loads"] == []
    blind = separate(None, disk, resolution=32, model_loads=False)
    patches = blind.summary["suspect_loads"]
    assert len(patches) == 2
    for patch in patches:
        assert abs(abs(patch["center_mm"][1]) - 20) < 1.5 and abs(patch["center_mm"][0]) < 1.5
        region = parse_region(patch["region"])
        assert region.contains(np.array([[0.0, np.sign(patch["center_mm"][1]) * 19.9, 0.0]]))[0]
    # Declaring them loaded, as the report says, gives the separation with the scene's own contacts back.
    given = separate(None, disk, resolution=32, model_loads=False, loaded=[p["region"] for p in patches])
    assert given.summary["suspect_loads"] == []


def test_a_loaded_region_can_be_a_closed_mesh(tmp_path):
    import trimesh
    disk = mi_nest.load_scene("disk_compression", contact_width="4", load="100")
    for sign in (1, -1):
        trimesh.creation.box(extents=(10, 3, 8)).apply_translation((0, sign * 20, 0)).export(tmp_path / f"{sign}.stl")
    meshes = separate(None, disk, resolution=32, model_loads=False,
                      loaded=[f"mesh:{tmp_path / '1.stl'}", f"mesh:{tmp_path / '-1.stl'}"])
    boxes = separate(None, disk, resolution=32, model_loads=False,
                     loaded=["box:-5,18.5,-4,5,21.5,4", "box:-5,-21.5,-4,5,-18.5,4"])
    assert meshes.summary["suspect_loads"] == [] and meshes.summary["loaded"] == {
        **boxes.summary["loaded"], "regions": meshes.summary["loaded"]["regions"]}
    assert np.allclose(meshes.mean, boxes.mean)
    trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]]).export(tmp_path / "open.stl")
    with pytest.raises(RegionError, match="not a closed surface"):
        separate(None, disk, resolution=16, loaded=[f"mesh:{tmp_path / 'open.stl'}"])
    with pytest.raises(RegionError, match="mesh file not found"):
        parse_region(f"mesh:{tmp_path / 'none.stl'}")


def test_what_cannot_be_separated_is_refused():
    tube = mi_nest.load_scene("lame_cylinder")
    with pytest.raises(RegionError, match="box:X0,Y0,Z0,X1,Y1,Z1 .mm. or mesh:PATH"):
        parse_region("sphere:0,0,0,1")
    with pytest.raises(RegionError, match="six finite numbers"):
        parse_region("box:0,0,0,1,1")
    with pytest.raises(RegionError, match="touches no surface of the part"):
        separate(None, tube, resolution=16, loaded=["box:100,100,100,110,110,110"])
    with pytest.raises(SeparationError, match="surface is free"):
        separate(None, tube, resolution=16, loaded=["box:-30,-30,-30,30,30,30"])
    zero = scene([box((10, 10, 10), interior=medium("uniform"))])
    with pytest.raises(SeparationError, match="no deviatoric stress"):
        separate(None, zero, resolution=16)
    flat = scene([{"type": "rectangle", "interior": medium("uniform", xx=1.0)}])
    with pytest.raises(SeparationError, match="not a closed mesh"):
        separate(None, flat, resolution=16)


def test_a_reconstruction_records_its_separation(tmp_path, capsys):
    simulate("disk_compression", tmp_path / "data", TINY, progress=False, defines={"load": 20})
    assert main(["reconstruct", str(tmp_path / "data"), "-o", str(tmp_path / "run"), "--iterations", "20",
                 "--resolution", "16", "--no-progress", "--allow-aliased"]) == 0
    assert main(["separate", str(tmp_path / "run"), "-o", str(tmp_path / "full")]) == 0
    record = json.loads((tmp_path / "run" / "reconstruction.json").read_text())
    assert record["separations"][0]["output"] == str((tmp_path / "full").resolve())
    assert record["separations"][0]["grid"] == list(mi_nest.Reconstruction.load(tmp_path / "run").field.shape)
    assert main(["separate", str(tmp_path / "run"), "-o", str(tmp_path / "full")]) == 0      # again: replaced
    assert len(json.loads((tmp_path / "run" / "reconstruction.json").read_text())["separations"]) == 1


def test_cli_writes_the_full_tensor_and_says_how_it_compares(tmp_path, capsys):
    out = tmp_path / "full"
    assert main(["separate", "lame_cylinder", "-o", str(out), "--resolution", "24"]) == 0
    printed = capsys.readouterr().out
    assert "mean stress separated on a" in printed and "against the truth" in printed
    summary = json.loads((out / "separation.json").read_text())
    assert summary["against_truth"]["all"]["mean_per_scale"] < 0.02
    assert summary["against_truth"]["all"]["deviatoric"] < 1e-4
    grid = load_stress_grid(out / "full.npz")                       # a stress grid any command reads
    assert grid.stress.shape[:3] == tuple(summary["grid"][::-1])
    assert (out / "separation.png").stat().st_size > 10_000
    assert main(["export", str(out / "full.npz"), "-o", str(tmp_path / "full.vtu")]) == 0
    capsys.readouterr()
    # The separation's directory is a source as a scene is: its principal stresses are full, with the mean stress.
    assert main(["principal", str(out), "--plane", "z=0", "-o", str(tmp_path / "p.png"), "--res", "48"]) == 0
    printed = capsys.readouterr().out
    assert "sigma_1" in printed and "deviatoric" not in printed
    mean_error, truth_rms = map(float, re.search(r"mean stress against the truth: RMS error (\S+) MPa \(truth's RMS "
                                                 r"(\S+) MPa\)", printed).groups())
    assert mean_error < 0.1 * truth_rms           # on this plane at 24 nodes, bore included (accuracy: above)
    # A virtual slice of it shows what the scene's own field shows: the fringes see the deviator only.
    for source, name in ((str(out), "full"), ("lame_cylinder", "scene")):
        assert main(["slice", source, "--plane", "z=0", "--thickness", "2", "-o", str(tmp_path / f"{name}.exr"),
                     "--res", "32"]) == 0
    capsys.readouterr()
    full, own = (read_channels(tmp_path / f"{name}.exr") for name in ("full", "scene"))
    order = "fringe.order"
    inside = own[order] > 0.05 * own[order].max()
    difference = full[order][inside] - own[order][inside]
    assert np.sqrt(np.mean(difference ** 2)) < 0.01 * own[order].max()      # the 24-node grid against the model
    assert main(["separate", "lame_cylinder", "-o", str(tmp_path / "bad"), "--loaded", "box:1,2"]) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0
    assert main(["separate", "lame_cylinder", "-o", str(tmp_path / "far"), "--loaded",
                 "box:100,100,100,110,110,110"]) == 2
    assert "touches no surface" in capsys.readouterr().err
