"""Virtual slices: a thin slab of the disk against Frocht's closed form, the stacked disks' two regions against
each other and against the integrator's own walk, and the slices that cannot be made."""
import math

import mitsuba as mi
import numpy as np
import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.views import Plane, Region, SliceError, SliceSpec, slice_render
from mi_nest.views.slicing import slice_image
from mi_nest.io.exr import read_channels
from mi_nest.physics import su2
from mi_nest.physics.polariscope import polariscope_setting
from mi_nest.scene import photoelastic_integrator

DIAMETER, LOAD, FRINGE_VALUE = 40.0, 1000.0, 10.6


def frocht(x, y, load=LOAD, thickness=6.0, diameter=DIAMETER, load_angle=0.0):
    """Frocht's plane stress of a disk squeezed along its y axis turned by ``load_angle`` (degrees, about z):
    ``(sigma_1 - sigma_2, angle of sigma_1 from x in degrees)`` at world points."""
    phi = math.radians(load_angle)
    xd, yd = x * math.cos(phi) + y * math.sin(phi), -x * math.sin(phi) + y * math.cos(phi)
    r = 0.5 * diameter
    r1, r2 = xd ** 2 + (r - yd) ** 2, xd ** 2 + (r + yd) ** 2
    k = 2 * load / (math.pi * thickness)
    sx = -k * ((r - yd) * xd ** 2 / r1 ** 2 + (r + yd) * xd ** 2 / r2 ** 2 - 1 / diameter)
    sy = -k * ((r - yd) ** 3 / r1 ** 2 + (r + yd) ** 3 / r2 ** 2 - 1 / diameter)
    txy = k * ((r - yd) ** 2 * xd / r1 ** 2 - (r + yd) ** 2 * xd / r2 ** 2)
    difference = np.sqrt((sx - sy) ** 2 + 4 * txy ** 2)
    angle = 0.5 * np.degrees(np.arctan2(2 * txy, sx - sy)) + load_angle
    return difference, angle


def pixel_points(scene, spec):
    image = slice_image(scene, spec.plane, spec.resolution)
    return image.centres().reshape(image.height, image.width, 3)


def away_from_loads(points, diameter=DIAMETER, fraction=0.8):
    return np.hypot(points[..., 0], points[..., 1]) < fraction * 0.5 * diameter


def angle_difference(a, b):
    """Degrees between two axes (mod 180)."""
    return np.abs((a - b + 90.0) % 180.0 - 90.0)


@pytest.fixture(scope="module")
def disk():
    return mi_nest.load_scene("disk_compression", res=32)


@pytest.mark.parametrize("kind", ["circular", "linear"])
def test_a_thin_slice_of_the_disk_is_frochts_plane_fringes_of_that_thickness(disk, kind):
    thickness = 1.5
    spec = SliceSpec(Plane.parse("z=0.7"), thickness, resolution=96, polariscope=polariscope_setting(kind))
    result = slice_render(disk, spec)
    points = pixel_points(disk, spec)
    difference, angle = frocht(points[..., 0], points[..., 1])
    order = thickness * difference / FRINGE_VALUE
    keep = away_from_loads(points)
    assert np.abs(result.channels["fringe.order"] - order)[keep].max() < 1e-3 * order[keep].max()
    dark = np.sin(math.pi * order) ** 2
    if kind == "linear":      # crossed polariser and analyser at 90 and 0 degrees: isoclinics of 0 and 90
        dark = dark * np.sin(2 * np.radians(angle)) ** 2
    assert np.abs(result.main - dark)[keep].max() < 2e-3
    defined = keep & (order > 0.05)
    assert angle_difference(result.channels["isoclinic.angle"], angle)[defined].max() < 0.1
    assert (result.channels["slab.mask"][keep] == 1).all()
    assert np.abs(result.channels["path.length"][keep] - thickness).max() < 1e-4


def test_a_light_field_is_the_dark_fields_complement(disk):
    plane = Plane.parse("z=0")
    dark, light = (slice_render(disk, SliceSpec(plane, 2.0, resolution=48, polariscope=polariscope_setting(field=f)))
                   for f in ("dark", "light"))
    inside = dark.channels["slab.mask"] == 1
    assert np.abs(dark.main + light.main - 1.0)[inside].max() < 1e-5
    # Beside the slab the light passes unchanged: the polariscope's own background.
    assert np.abs(dark.main[~inside]).max() < 1e-6 and np.abs(light.main[~inside] - 1).max() < 1e-6


def test_the_load_scale_and_the_wavelength_scale_the_order(disk):
    plane = Plane.parse("z=0")
    base = slice_render(disk, SliceSpec(plane, 1.0, resolution=32)).channels["fringe.order"]
    for scale, wavelength, factor in ((2.0, None, 2.0), (1.0, 266.0, 2.0), (0.5, 1064.0, 0.25)):
        scaled = slice_render(disk, SliceSpec(plane, 1.0, resolution=32, load_scale=scale,
                                              wavelength=wavelength)).channels["fringe.order"]
        assert np.allclose(scaled, factor * base, rtol=1e-4, atol=1e-5)


@pytest.fixture(scope="module")
def stacked():
    # 24 steps of 0.5 mm through the stack whether a chord is measured as 12 or as 12.000001 mm: the disks'
    # interface then falls between steps in every march (a step across it samples one disk for both).
    return mi_nest.load_scene("stacked_disks", res=32, step=0.5001)


def test_each_region_of_the_stacked_disks_shows_its_own_disk(stacked):
    plane = Plane.parse("z=0")
    points = pixel_points(stacked, SliceSpec(plane, 12.0, resolution=64))
    keep = away_from_loads(points)
    for region, load_angle, other in (("box:-30,-30,-7,30,30,0", 0.0, 45.0), ("box:-30,-30,0,30,30,7", 45.0, 0.0)):
        result = slice_render(stacked, SliceSpec(plane, 12.0, Region.parse(region), resolution=64))
        expected = np.sin(math.pi * 6.0 * frocht(points[..., 0], points[..., 1], 600.0,
                                                 load_angle=load_angle)[0] / FRINGE_VALUE) ** 2
        wrong = np.sin(math.pi * 6.0 * frocht(points[..., 0], points[..., 1], 600.0,
                                              load_angle=other)[0] / FRINGE_VALUE) ** 2
        assert np.abs(result.main - expected)[keep].max() < 2e-3
        assert np.abs(result.main - wrong)[keep].mean() > 0.1
        assert np.abs(result.channels["path.length"][keep] - 6.0).max() < 1e-4


def test_the_regions_jones_products_in_the_lights_order_are_the_walks_product(stacked):
    plane = Plane.parse("z=0")
    spec = SliceSpec(plane, 12.0, resolution=48)
    jones = lambda result: tuple(result.channels[f"jones.{k}"].astype(np.float64) for k in "abcd")
    whole = slice_render(stacked, spec)
    first, second = (jones(slice_render(stacked, SliceSpec(plane, 12.0, Region.parse(box), resolution=48)))
                     for box in ("box:-30,-30,-7,30,30,0", "box:-30,-30,0,30,30,7"))
    # The light crosses z < 0 first: the later element multiplies on the left.
    product = su2.multiply(second, first)
    inside = whole.channels["slab.mask"] == 1
    assert max(np.abs(p - w)[inside].max() for p, w in zip(product, jones(whole))) < 1e-4
    reversed_order = su2.multiply(first, second)
    assert max(np.abs(p - w)[inside].max() for p, w in zip(reversed_order, jones(whole))) > 0.1
    # The same lines through the integrator's own walk (Embree's crossings, the scene's steps).
    points = pixel_points(stacked, spec).reshape(-1, 3)
    count = len(points)
    rays = mi.Ray3f(mi.Point3f(*(points + [0, 0, 50]).T.astype(np.float32)),
                    mi.Vector3f(*np.tile([0.0, 0.0, -1.0], (count, 1)).T.astype(np.float32)))
    traced = photoelastic_integrator(stacked).tracer.trace_rays(stacked, rays,
                                                                mi.Vector3f(*np.tile([1.0, 0, 0], (count, 1)).T))
    walked = [np.array(x).reshape(inside.shape) for x in traced.jones()]
    # Float32 points a few micrometres apart: near the point loads the stress changes too fast for 1e-4.
    keep = inside & away_from_loads(points.reshape(*inside.shape, 3), fraction=0.9)
    assert max(np.abs(p - w)[keep].max() for p, w in zip(walked, jones(whole))) < 1e-4


def test_a_mesh_region_keeps_its_inside(stacked, tmp_path):
    import trimesh
    path = tmp_path / "upper.ply"
    trimesh.creation.box(extents=(60, 60, 7), transform=trimesh.transformations.translation_matrix([0, 0, 3.5])
                         ).export(path)
    plane = Plane.parse("z=0")
    mesh = slice_render(stacked, SliceSpec(plane, 12.0, Region.parse(str(path)), resolution=32))
    box = slice_render(stacked, SliceSpec(plane, 12.0, Region.parse("box:-30,-30,0,30,30,7"), resolution=32))
    assert np.abs(mesh.main - box.main).max() < 1e-5


def test_a_slice_beside_the_part_or_its_region_is_refused_in_one_line(disk, capsys, tmp_path):
    with pytest.raises(SliceError, match="holds none of the part: the specimens span -3 to 3 mm along the normal"):
        slice_render(disk, SliceSpec(Plane.parse("z=10"), 1.0, resolution=16))
    with pytest.raises(SliceError, match="or the region"):
        slice_render(disk, SliceSpec(Plane.parse("z=0"), 1.0, Region.parse("box:50,50,-1,60,60,1"), resolution=16))
    output = tmp_path / "slice.exr"
    assert main(["slice", "disk_compression", "--plane", "z=9", "--thickness", "1", "-o", str(output)]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "move the plane into that range" in error
    assert not output.exists()


@pytest.mark.parametrize("arguments, message", [
    (["--plane", "w=0"], "--plane must be x=MM"),
    (["--plane", "z=abc"], "finite number of mm"),
    (["--normal", "0,0"], "three comma-separated numbers"),
    (["--normal", "0,0,0"], "not all zero"),
    (["--plane", "z=0", "--normal", "0,0,1"], "not both"),
    (["--plane", "z=0", "--region", "box:0,0,0,1,1"], "six numbers"),
    (["--plane", "z=0", "--region", "box:0,0,0,1,1,0"], "flat"),
    (["--plane", "z=0", "--region", "part.step"], "closed mesh file"),
    (["--plane", "z=0", "--region", "missing.ply"], "not found"),
    (["--plane", "z=0", "--thickness", "-1"], "positive number of mm"),
    (["--plane", "z=0", "--wavelength", "0"], "positive number of nm"),
])
def test_bad_slice_options_get_one_line(arguments, message, capsys, tmp_path):
    if "--thickness" not in arguments:
        arguments = arguments + ["--thickness", "1"]
    assert main(["slice", "disk_compression", *arguments, "-o", str(tmp_path / "s.exr")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error


def test_the_slice_command_writes_the_exr_and_its_pictures(tmp_path, capsys):
    output = tmp_path / "slice.exr"
    assert main(["slice", "stacked_disks", "--normal", "0,0,1", "--offset", "-3", "--thickness", "6",
                 "--res", "40", "--polariscope", "linear", "-o", str(output), "--png", str(tmp_path / "s.png"),
                 "--maps", str(tmp_path / "maps.png")]) == 0
    channels = read_channels(output)
    assert {"Y", "fringe.order", "isoclinic.angle", "slab.mask", "jones.a"} <= set(channels)
    assert channels["Y"].shape == (40, 40)
    assert (tmp_path / "s.png").stat().st_size > 0 and (tmp_path / "maps.png").stat().st_size > 0
