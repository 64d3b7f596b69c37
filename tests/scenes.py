"""Scene dictionaries for tests: slabs, meshes and a configurable polariscope."""
from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

import mi_nest  # noqa: F401  (selects the variant, registers the plugins)
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.fields.analytic import DiskCompressionField
from mi_nest.fields.base import sample
from mi_nest.io.grid import grid_nodes
from mi_nest.physics.tensors import deviatoric_part
from mi_nest.reconstruct import FieldConfig
from mi_nest.reconstruct.fields import DeviatoricGrid, stored_components

WAVELENGTH = 532.0
# The smallest dataset a reconstruction runs on (four rotations at 8 px, one held out), and a load that keeps its
# fringes resolved.
TINY = SimulationSettings(azimuths=2, elevations=2, res=8, spp=1, test_fraction=0.25)
GENTLE = {"load": 20}


def disk_deviator_grid(plant=None):
    """The 100 N disk's (4 mm contacts) deviator on a 32-node :class:`DeviatoricGrid` over its box, with
    ``plant(deviator, nodes)`` (3D-TSV order, mm) stored instead where given; and the grid's nodes and the exact
    deviator there."""
    grid = DeviatoricGrid(FieldConfig(kind="grid", resolution=32), np.array([-20.0, -20.0, -3.0]),
                          np.array([20.0, 20.0, 3.0]), 0.5)
    nx, ny, nz = grid.shape
    nodes = grid_nodes(grid.bbox_min, grid.bbox_max, grid.shape)
    truth = deviatoric_part(sample(DiskCompressionField(load=100, contact_width=4), nodes))
    values = truth if plant is None else plant(truth, nodes)
    grid.assign({"grid": mi.TensorXf(stored_components(values, grid.stress_scale)
                                     .reshape(nz, ny, nx, 5).astype(np.float32))})
    return grid, nodes, truth


def tiny_disk(directory, load: float):
    """The disk under ``load`` (N) simulated as :data:`TINY` into ``directory``; at 8 px its contacts alias, and the
    warning that says so is expected."""
    with pytest.warns(RuntimeWarning):
        simulate("disk_compression", directory, TINY, progress=False, defines={"load": load})
    return directory
BREWSTER = 50.0
# A 6 mm cube of uniform stress ``xx = {stress}`` as a scene file's element (a format string).
UNIFORM_CUBE_XML = """    <shape type="cube">
        <transform name="to_world"><scale value="3"/></transform>
        <medium type="stress" name="interior">
            <float name="stress_optic_coefficient" value="50"/>
            <string name="model" value="uniform"/>
            <float name="xx" value="{stress}"/>
        </medium>
    </shape>
"""


def medium(model="uniform", C=BREWSTER, **params):
    return {"type": "stress", "model": model, "stress_optic_coefficient": C, **params}


def box(size, center=(0.0, 0.0, 0.0), interior=None):
    """A closed box (Mitsuba's cube) of ``size`` (mm) centred at ``center``."""
    shape = {"type": "cube",
             "to_world": mi.ScalarTransform4f().translate(list(center)).scale([0.5 * s for s in size])}
    if interior is not None:
        shape["interior"] = interior
    return shape


def scene(shapes, *, res=4, view=5.0, step=0.5, polarizer=90.0, input_qwp=None, output_qwp=None,
          analyzer=0.0, origin=(0.0, 0.0, 100.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0),
          projection="orthographic", fov=20.0, jitter=False, spp=1, sampler="stratified",
          pixel_format="luminance", light_optics=None, camera_optics=None, **integrator):
    """A photoelastic scene; the default camera looks down -z (image right +x, up +y). ``light_optics`` and
    ``camera_optics`` (the plugins' ``optics`` strings) replace the polariser and waveplate and the analyser."""
    light = {"type": "polariscope_light", "polarizer": polarizer}
    if input_qwp is not None:
        light["qwp"] = input_qwp
    to_world = mi.ScalarTransform4f().look_at(origin=list(origin), target=list(target), up=list(up))
    if projection == "orthographic":
        to_world = to_world @ mi.ScalarTransform4f().scale([view, view, 1.0])
    sensor = {"type": "polariscope", "projection": projection, "to_world": to_world,
              "film": {"type": "hdrfilm", "width": res, "height": res, "pixel_format": pixel_format,
                       "rfilter": {"type": "box"}},
              "sampler": {"type": sampler, "sample_count": spp}}
    if sampler == "stratified":
        sensor["sampler"]["jitter"] = False
    if projection == "perspective":
        sensor["fov"] = fov
    if analyzer is not None:
        sensor["analyzer"] = analyzer
    if output_qwp is not None:
        sensor["qwp"] = output_qwp
    if light_optics is not None:
        light = {"type": "polariscope_light", "optics": light_optics}
    if camera_optics is not None:
        sensor = {key: value for key, value in sensor.items() if key not in ("analyzer", "qwp")}
        sensor["optics"] = camera_optics
    description = {"type": "scene", "embree_use_robust_intersections": True,
                   "integrator": {"type": "photoelastic", "step_size": step, "jitter": jitter, **integrator},
                   "light": light, "sensor": sensor}
    for index, shape in enumerate(shapes):
        description[f"specimen_{index}"] = shape
    return mi.load_dict(description)


def render(shapes, **options):
    return mi_nest.render(scene(shapes, **options)).channels
