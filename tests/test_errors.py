"""Bad input gets a clear error naming the problem, never a crash or a black image."""
import math

import mitsuba as mi
import numpy as np
import pytest

import mi_nest
from mi_nest.io.grid import GridFileError, load_stress_grid
from scenes import box, medium, scene

SCENE_XML = """<scene version="3.0.0">
    <integrator type="photoelastic"><float name="step_size" value="{step}"/></integrator>
    <emitter type="polariscope_light"/>
    <sensor type="polariscope">
        <film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/></film>
    </sensor>
    <shape type="cube">
        <medium type="stress" name="interior">
            <float name="stress_optic_coefficient" value="50"/>
            {field}
        </medium>
    </shape>
</scene>"""


def load_xml(tmp_path, field='<string name="model" value="uniform"/>', step="0.5"):
    path = tmp_path / "scene.xml"
    path.write_text(SCENE_XML.format(field=field, step=step))
    return mi_nest.load_scene(path)


def write_grid(path, stress, bbox_min=(0, 0, 0), bbox_max=(1, 1, 1)):
    np.savez(path, stress=stress, bbox_min=np.array(bbox_min, float), bbox_max=np.array(bbox_max, float))
    return path


def test_a_valid_scene_loads(tmp_path):
    assert load_xml(tmp_path) is not None


def test_missing_field_file(tmp_path):
    with pytest.raises(mi_nest.SceneError, match="stress file not found: .*nowhere.npz"):
        load_xml(tmp_path, f'<string name="filename" value="{tmp_path}/nowhere.npz"/>')


def test_unknown_model_lists_the_available_ones(tmp_path):
    with pytest.raises(mi_nest.SceneError, match="unknown model 'disk'.*disk_compression"):
        load_xml(tmp_path, '<string name="model" value="disk"/>')


def test_unknown_model_parameter_is_named(tmp_path):
    with pytest.raises(mi_nest.SceneError, match="diamter"):
        load_xml(tmp_path, '<string name="model" value="disk_compression"/><float name="diamter" value="3"/>')


@pytest.mark.parametrize("shape", [(4, 4, 4, 5), (4, 4, 6), (1, 4, 4, 6)])
def test_wrong_grid_shape(tmp_path, shape):
    path = write_grid(tmp_path / "bad.npz", np.zeros(shape, np.float32))
    with pytest.raises(GridFileError, match=r"shape \(Z, Y, X, 6\)|at least 2 nodes"):
        load_stress_grid(path)
    with pytest.raises(mi_nest.SceneError, match="bad.npz"):
        load_xml(tmp_path, f'<string name="filename" value="{path}"/>')


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_stress_in_a_grid(tmp_path, bad):
    stress = np.zeros((3, 3, 3, 6), np.float32)
    stress[1, 2, 0, 4] = bad
    path = write_grid(tmp_path / "nan.npz", stress)
    with pytest.raises(GridFileError, match=r"NaN or inf \(first at index \(1, 2, 0, 4\)\)"):
        load_stress_grid(path)


def test_non_finite_model_parameter(tmp_path):
    with pytest.raises(mi_nest.SceneError, match="'xx' must be finite"):
        load_xml(tmp_path, '<string name="model" value="uniform"/><float name="xx" value="nan"/>')


def test_grid_with_missing_arrays_or_garbage(tmp_path):
    np.savez(tmp_path / "partial.npz", stress=np.zeros((2, 2, 2, 6)))
    with pytest.raises(GridFileError, match=r"missing array\(s\) \['bbox_max', 'bbox_min'\]"):
        load_stress_grid(tmp_path / "partial.npz")
    (tmp_path / "garbage.npz").write_bytes(b"not a zip file")
    with pytest.raises(GridFileError, match="not a readable .npz"):
        load_stress_grid(tmp_path / "garbage.npz")
    write_grid(tmp_path / "flat.npz", np.zeros((2, 2, 2, 6)), bbox_max=(1, 0, 1))
    with pytest.raises(GridFileError, match="bbox_max .* must exceed bbox_min"):
        load_stress_grid(tmp_path / "flat.npz")


@pytest.mark.parametrize("step", ["-0.5", "0", "nan"])
def test_non_positive_step(tmp_path, step):
    with pytest.raises(mi_nest.SceneError, match="'step_size' must be a positive length"):
        load_xml(tmp_path, step=step)


def test_material_is_required_once(tmp_path):
    # Mitsuba re-raises a plugin's ValueError as RuntimeError, keeping the message.
    with pytest.raises(RuntimeError, match="exactly one of 'stress_optic_coefficient'"):
        mi.load_dict({"type": "stress", "model": "uniform"})
    with pytest.raises(RuntimeError, match="exactly one of 'stress_optic_coefficient'"):
        mi.load_dict({"type": "stress", "model": "uniform", "fringe_value": 10.0,
                      "stress_optic_coefficient": 50.0})
    with pytest.raises(RuntimeError, match="exactly one of 'filename'"):
        mi.load_dict({"type": "stress", "fringe_value": 10.0})


def test_scene_without_stress_medium():
    plain = scene([box((2, 2, 2))])
    with pytest.raises(Exception, match="the scene has no specimen"):
        mi_nest.render(plain)


def test_scene_without_polariscope_light():
    description = {"type": "scene", "integrator": {"type": "photoelastic"},
                   "sensor": {"type": "polariscope", "film": {"type": "hdrfilm", "width": 2, "height": 2}},
                   "specimen": box((2, 2, 2), interior=medium(xx=1.0))}
    with pytest.raises(Exception, match='exactly one <emitter type="polariscope_light">, found 0'):
        mi_nest.render(mi.load_dict(description))


def test_unknown_projection_and_bad_angles():
    with pytest.raises(RuntimeError, match="unknown projection 'fisheye'"):
        mi.load_dict({"type": "polariscope", "projection": "fisheye"})
    with pytest.raises(RuntimeError, match="angle 'analyzer' must be finite"):
        mi.load_dict({"type": "polariscope", "analyzer": math.inf})


def test_missing_scene_file_and_unknown_shipped_scene(tmp_path):
    with pytest.raises(mi_nest.SceneError, match="scene file not found"):
        mi_nest.load_scene(tmp_path / "absent.xml")
    with pytest.raises(mi_nest.SceneError, match="no shipped scene 'disc'.*disk_compression"):
        mi_nest.load_scene("disc")


def test_scene_with_another_integrator():
    description = {"type": "scene", "integrator": {"type": "path"},
                   "light": {"type": "polariscope_light"},
                   "sensor": {"type": "polariscope", "film": {"type": "hdrfilm", "width": 2, "height": 2}},
                   "specimen": box((2, 2, 2), interior=medium(xx=1.0))}
    with pytest.raises(mi_nest.SceneError, match='integrator is PathIntegrator.*type="photoelastic"'):
        mi_nest.render(mi.load_dict(description))


def test_open_specimen_surfaces_are_refused(tmp_path):
    import trimesh
    box_mesh = trimesh.creation.box(extents=(4, 4, 4))
    open_box = trimesh.Trimesh(box_mesh.vertices, box_mesh.faces[2:], process=False)
    open_box.export(tmp_path / "open.ply")
    shapes = [{"type": "ply", "filename": str(tmp_path / "open.ply"), "interior": medium(xx=1.0)}]
    with pytest.raises(ValueError, match=r"not a closed mesh \(4 edges"):
        mi_nest.render(scene(shapes))
    with pytest.raises(ValueError, match=r"\(Cylinder\) is not a closed surface"):
        mi_nest.render(scene([{"type": "cylinder", "interior": medium(xx=1.0)}]))
    # A sphere and the cube are closed.
    assert mi_nest.render(scene([{"type": "sphere", "radius": 2.0, "interior": medium(xx=1.0)}])).main.max() > 0
