"""``mi-nest demo``: the whole loop on the default scene: render, simulate a dataset, reconstruct, compare."""
from __future__ import annotations

import math
import warnings
from pathlib import Path

from .dataset import Dataset, SimulationSettings, simulate
from .reconstruct import Reconstruction, optimize
from .reconstruct.metrics import floor_bounds_nothing
from .reconstruct.outputs import write_test_view, write_truth_beside_reconstruction
from .render import render
from .scene import load_scene, scene_path, specimen_media

DEFAULT_SCENE = "disk_compression"
# The demo's loop: a load whose fringes a 48x48 camera resolves, spread over a 4 mm contact as platens do (point
# loads are 1/r singular: no grid could hold them). At 100 N the fringes alias in half the views and the fit
# settles in wrapped minima (34 to 69% error); at 60 N, with the targets' regulariser, 10.6% for two seeds.
DEMO_LOAD, DEMO_CONTACT, DEMO_RES, DEMO_ROTATIONS = 60.0, 4.0, 48, 12
# The defaults, shortened to a demo's length: a fifth of their iterations, on a grid with half the nodes along
# each axis that the disk's thickness would get (eight times fewer unknowns for the shorter run).
DEMO_GRID, DEMO_ITERATIONS = 32, 4000


def run_demo(output_dir: str | Path, iterations: int = DEMO_ITERATIONS) -> Reconstruction:
    """Render the default scene, then the whole NeST loop on it: simulate, reconstruct, compare."""
    out = Path(output_dir)
    scene = load_scene(scene_path(DEFAULT_SCENE))
    result = render(scene, progress=True)
    result.write(out / f"{DEFAULT_SCENE}.exr", png=out / f"{DEFAULT_SCENE}.png")
    medium, = specimen_media(scene)
    disk = medium.field
    order = 8 * disk.load / (math.pi * disk.diameter * medium.fringe_value)
    print(f"disk under diametral compression, dark-field circular polariscope: closed-form fringe order "
          f"at the centre {order:.3f}; main channel in [{result.main.min():.3f}, {result.main.max():.3f}]")

    defines = {"load": DEMO_LOAD, "contact_width": DEMO_CONTACT}
    print(f"NeST loop: {DEMO_ROTATIONS}x{DEMO_ROTATIONS} rotations at {DEMO_RES}x{DEMO_RES}, load {DEMO_LOAD:g} N "
          f"over {DEMO_CONTACT:g} mm contacts")
    settings = SimulationSettings(azimuths=DEMO_ROTATIONS, elevations=DEMO_ROTATIONS, res=DEMO_RES)
    with warnings.catch_warnings():
        # The load points are singular: a few pixels there always alias; the loop works around them.
        warnings.simplefilter("ignore", RuntimeWarning)
        report = simulate(scene_path(DEFAULT_SCENE), out / "dataset", settings, defines=defines)
    print(report.describe())
    dataset = Dataset(out / "dataset")
    aliasing = dataset.index.get("fringe_aliasing")
    if aliasing and aliasing["views"]:
        print(f"fringes denser than the pixels in {aliasing['views']} of {aliasing['of']} views, "
              f"over {100 * aliasing['mean_fraction']:.1f}% of the disk's pixels on average")
    loop_scene = load_scene(scene_path(DEFAULT_SCENE), res=DEMO_RES, **defines)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", ".*fringes are denser than the pixels", RuntimeWarning)   # said above
        reconstruction = optimize(loop_scene, dataset, output=out / "reconstruction", resolution=DEMO_GRID,
                                  iterations=iterations)
    print(reconstruction.describe())
    written = write_test_view(loop_scene, reconstruction, out / "reconstruction", dataset)
    default_view = load_scene(scene_path(DEFAULT_SCENE), **defines)
    comparison = write_truth_beside_reconstruction(default_view, reconstruction, out)
    found = reconstruction.metrics
    floor = ("" if floor_bounds_nothing(reconstruction.field, found["grid_floor"], found["evaluation_points"]) else
             f" (the floor: the least-squares fit of the true field by this {reconstruction.field.describe()} "
             f"scores {100 * found['grid_floor']:.1f}%)")
    print(f"relative deviatoric stress error: {100 * found['deviatoric_error']:.1f}%{floor}")
    print(f"wrote {(out / 'reconstruction').resolve()} (field.npz, reconstruction.json{written}) and {comparison}")
    return reconstruction
