"""The ``mi-nest`` command line: argument parsing and a table from command to handler; the work lives in
the package."""
from __future__ import annotations

import argparse
import math
import signal
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from . import interrupts, variants
from .demo import DEFAULT_SCENE, DEMO_ITERATIONS, run_demo
from .views.slicing import REGION_HELP
from .io.atomic import require_file_path
from .physics.polariscope import POLARISCOPE_FIELDS, POLARISCOPE_KINDS
from .reconstruct import KIND_CHOICES, METHODS, DivergenceError
from .rig.errors import RigError
from .scene import parse_define


# `mi-nest reconstruct --minutes` without --iterations: the clock alone ends the run.
UNBOUNDED_ITERATIONS = 10 ** 9
# The options of `mi-nest reconstruct` besides those it names: `--option NAME=VALUE` (any of optimize's).
OPTION_EXAMPLES = "batch_size=4096, learning_rate=0.03, smoothness=0, average_last=0, seed=1, warm_start=0.2"


def _parser():
    parser = argparse.ArgumentParser(prog="mi-nest", description="Photoelastic stress tomography in Mitsuba 3.")
    parser.add_argument("--variant", help="Mitsuba variant to run on: llvm_ad_mono (the CPU, default), cuda_ad_mono "
                                          "(a GPU) or auto (the GPU where there is one); the environment's "
                                          "MI_NEST_VARIANT otherwise")
    commands = parser.add_subparsers(dest="command", required=True)

    render = commands.add_parser("render", help="render a scene, or a reconstruction from any view, to a "
                                                 "multichannel EXR")
    render.add_argument("scene", help="scene XML file, or the name of a shipped scene, or a reconstruction "
                                      "directory (its field in the scene it was reconstructed with)")
    render.add_argument("-o", "--output", required=True, help="output EXR path")
    render.add_argument("--azimuth", type=float, default=0.0,
                        help="turn the specimen about the camera's up axis (degrees, as datasets do; default: 0)")
    render.add_argument("--elevation", type=float, default=0.0,
                        help="and about the camera's right axis (degrees; default: 0)")
    _add_polariscope_options(render)
    render.add_argument("-D", dest="defines", action="append", type=parse_define, default=[],
                        metavar="NAME=VALUE", help="fill the scene's $NAME default (repeatable)")
    render.add_argument("--png", help="also write a PNG preview of the main channel (of the colours in white light)")
    render.add_argument("--white-light", action="store_true",
                        help="in a white LED's light: a colour image (R, G, B), its luminance and each wavelength's "
                             "intensity (docs/physics.md section 9)")
    render.add_argument("--spp", type=int, help="samples per pixel (overrides the scene)")
    render.add_argument("--seed", type=int, default=0, help="random seed")
    render.add_argument("--quiet", action="store_true", help="no progress bar")

    demo = commands.add_parser("demo", help="the whole loop on the default scene (disk under diametral "
                                            "compression): render, simulate a dataset, reconstruct, compare")
    demo.add_argument("-o", "--output-dir", default="mi_nest_out", help="where to write (default: mi_nest_out)")
    demo.add_argument("--iterations", type=int, default=DEMO_ITERATIONS,
                      help=f"reconstruction iterations (default: {DEMO_ITERATIONS})")

    export = commands.add_parser("export", help="write a stress field as VTK (.vtu) for ParaView or as 3D-TSV "
                                                 "(.TSV) for its stress lines")
    export.add_argument("field", help="stress file (grid or mesh .npz, 3D-TSV .TSV/.stress or .TSVcarti/.carti), "
                                      "or a scene (XML file or shipped name) or a reconstruction directory, whose "
                                      "specimens are sampled on grids (a reconstruction's .vtu also holds its trust "
                                      "map)")
    export.add_argument("-o", "--output", required=True, help="output path: .vtu or .TSV")
    export.add_argument("-D", dest="defines", action="append", type=parse_define, default=[],
                        metavar="NAME=VALUE", help="fill a scene's $NAME default (repeatable)")
    export.add_argument("--resolution", type=int, default=64,
                        help="grid nodes along the longest axis when sampling (default: 64)")

    fem = commands.add_parser(
        "fem", help="solve a linear-elastic FEM model and write its nodal stress (.npz)",
        description="Either --spec FILE (TOML/JSON: geometry, material, loads, fixtures), or a MESH "
                    "(a volume mesh meshio reads, or a closed surface meshed with the gmsh extra) with "
                    "--fix/--load/--pressure. A 3D-TSV stress file as MESH (.TSV, .stress, .TSVcarti, .carti) "
                    "brings its own fixed nodes and node forces; flags add to them. WHERE is x=<v>, y=<v>, "
                    "z=<v> (a plane) or a surface group name of the mesh file.")
    fem.add_argument("mesh", nargs="?", help="volume mesh, closed surface or 3D-TSV stress file")
    fem.add_argument("--spec", help="model file (.toml or .json)")
    fem.add_argument("--fix", action="append", default=[], metavar="WHERE[:xyz]",
                     help="clamp the faces in WHERE (optionally only some components); repeatable")
    fem.add_argument("--load", action="append", default=[], metavar="WHERE:FX,FY,FZ",
                     help="total force (N) spread over the faces in WHERE; repeatable")
    fem.add_argument("--pressure", action="append", default=[], metavar="WHERE:P",
                     help="pressure (MPa, positive pushes in) on the faces in WHERE; repeatable")
    fem.add_argument("--material", default="3000,0.37", metavar="E,NU",
                     help="Young's modulus (MPa) and Poisson's ratio (default: epoxy 3000,0.37)")
    fem.add_argument("--element-size", type=float, help="mesh size (mm) when meshing a surface")
    fem.add_argument("-o", "--output", required=True, help="output mesh stress .npz (a specimen's filename)")
    fem.add_argument("--order", type=int, choices=(1, 2), help="element order (overrides the spec)")

    bench = commands.add_parser("bench", help="benchmarks")
    bench_kind = bench.add_subparsers(dest="bench", required=True)
    accuracy = bench_kind.add_parser("accuracy", help="speed against accuracy of the integration methods")
    accuracy.add_argument("--scenes", help="comma-separated cases (default: all of disk, twisted, stacked, "
                                           "kitten, dense)")
    accuracy.add_argument("--res", type=int, default=256, help="image resolution (default: 256)")
    accuracy.add_argument("-o", "--output-dir", default="mi_nest_out/bench", help="where the CSV and PNG go")

    simulate = commands.add_parser("simulate", help="render a multi-axis polariscope dataset of a scene")
    simulate.add_argument("scene", help="scene XML file or shipped scene name")
    simulate.add_argument("-o", "--output", required=True, help="dataset directory (resumed if interrupted)")
    simulate.add_argument("--azimuth", type=int, default=32, help="azimuth rotations (default: 32)")
    simulate.add_argument("--elevation", type=int, default=32, help="elevation rotations (default: 32)")
    simulate.add_argument("--azimuth-range", type=float, default=180.0, help="degrees (default: 180)")
    simulate.add_argument("--elevation-range", type=float, default=180.0, help="degrees (default: 180)")
    simulate.add_argument("--res", type=int, help="image width and height (the scene's $res)")
    simulate.add_argument("--spp", type=int, help="samples per pixel")
    simulate.add_argument("--noise", type=float, default=0.0, help="Gaussian read noise sigma (the paper: 0.01)")
    simulate.add_argument("--full-well", type=float, help="electrons at intensity 1: adds photon shot noise")
    simulate.add_argument("--bits", type=int, choices=(8, 10, 12, 16), help="quantise to this many bits")
    simulate.add_argument("--mosaic", action="store_true",
                          help="capture through the IMX250MZR 2x2 micro-polariser mosaic and demosaic")
    simulate.add_argument("--bands", help="colour bands, each with its 16 measurements: 'rgb' (a colour camera's "
                                          "red, green and blue under the white LED), wavelengths in nm "
                                          "('450,532,633': narrow bands) or a CSV of a camera's curves "
                                          "(wavelength,<band>,...); with --mosaic, the IMX250MYR's colour "
                                          "polarisation mosaic (default: one wavelength, the scene's)")
    simulate.add_argument("--seed", type=int, default=0, help="noise seed (default: 0)")
    simulate.add_argument("--test-fraction", type=float, default=0.2, help="rotations held out (default: 0.2)")
    simulate.add_argument("--float", action="store_true", help="store float32 instead of half floats")
    simulate.add_argument("-D", dest="defines", action="append", default=[], type=parse_define, metavar="NAME=VALUE",
                          help="set a scene $parameter")
    simulate.add_argument("--scheduler", help="render the rotations as tasks on Dask: 'local' (a cluster of processes "
                                              "on this machine) or a scheduler's address (tcp://host:8786)")
    simulate.add_argument("--workers", type=int, help="processes of a local cluster (default: the cores)")

    sweep = commands.add_parser("sweep", help="many cases (simulate, reconstruct, evaluate) from a TOML file, as "
                                              "tasks on Dask")
    sweep.add_argument("file", help="sweep file: the base scene, the dataset and reconstruction settings and the "
                                    "values to vary (docs/cluster.md)")
    sweep.add_argument("-o", "--output", required=True, help="where the cases, sweep.csv and sweep.png go; a rerun "
                                                             "runs only the cases not finished")
    sweep.add_argument("--scheduler", default="local", help="'local' (default: a cluster of processes on this "
                                                            "machine) or a Dask scheduler's address")
    sweep.add_argument("--workers", type=int, help="cases at once on a local cluster (default: 1; each case uses "
                                                   "its share of the cores)")
    sweep.add_argument("--no-progress", action="store_true", help="no progress bar")

    show = commands.add_parser("show", help="contact sheet PNG of a dataset, or a preview PNG of a mesh stress "
                                            "file with its boundary conditions")
    show.add_argument("dataset", help="dataset directory, or a mesh stress file (3D-TSV .TSV/.stress/.TSVcarti/"
                                      ".carti, mesh .npz)")
    show.add_argument("-c", "--channel", help="channel to tile (default: pol.45.0.0, or the first band's)")
    show.add_argument("-o", "--output", help="PNG path (default: DATASET/contact_sheet.png; for a file, "
                                             "<name>_preview.png in the current directory)")

    reconstruct = commands.add_parser("reconstruct", help="reconstruct the stress field from a dataset (NeST)")
    reconstruct.add_argument("dataset", help="dataset directory (from mi-nest simulate or acquire)")
    reconstruct.add_argument("-o", "--output", required=True, help="result directory (checkpoints, field, renders)")
    reconstruct.add_argument("--scene", help="scene with the specimen, material and camera (default: the scene the "
                                             "dataset was simulated from, with its defines)")
    reconstruct.add_argument("-D", dest="defines", action="append", type=parse_define, default=[],
                             metavar="NAME=VALUE", help="fill the scene's $NAME default (repeatable)")
    reconstruct.add_argument("--kind", choices=tuple(KIND_CHOICES), default="auto",
                             help="field representation (default: auto, the cheapest that fits)")
    reconstruct.add_argument("--iterations", type=int, help="(default: 20000, what the targets needed)")
    reconstruct.add_argument("--minutes", type=float,
                             help="optimise for this long; the learning rate and the coarse-to-fine stages then "
                                  "follow the clock (with --iterations too, whichever ends first)")
    reconstruct.add_argument("--resolution", type=int,
                             help="nodes along the longest axis of the grid, or of the lattice a hash grid or MLP is "
                                  "sampled on (default: 32, 48 or 64, the coarsest that puts 10 nodes across the "
                                  "specimen's thinnest side; 0: a network evaluated at every step, as NeST does)")
    reconstruct.add_argument("--fast", action="store_true",
                             help="the defaults' schedule about 3x faster, ending about 0.1 to 0.2 points of stress "
                                  "error above them (FAST_OPTIONS: 10,800 iterations of 1,024 pixels, 70%% of them "
                                  "on the final grid, 1 ray per pixel in the coarse stages; flags and --option "
                                  "given override it)")
    reconstruct.add_argument("--deterministic", action="store_true",
                             help="one CPU thread, so that a seeded run of --iterations repeats bit for bit (two "
                                  "threads sum the gradients in varying order; see docs/reconstruction.md for the "
                                  "cost)")
    reconstruct.add_argument("--no-regulariser", action="store_true",
                             help="the plain fit, without the grid's default smoothness and iterate averaging")
    reconstruct.add_argument("--option", dest="options", action="append", type=parse_define, default=[],
                             metavar="NAME=VALUE", help=f"any other option of mi_nest.optimize (repeatable; e.g. "
                                                        f"{OPTION_EXAMPLES}; docs/reconstruction.md lists them)")
    reconstruct.add_argument("--method", choices=METHODS,
                             help="forward model (default: product, NeST-general; linear is NeST-approx; two-step "
                                  "is the baseline: per-view unwrapping, then linear tomography)")
    reconstruct.add_argument("--start", metavar="FIELD",
                             help="start from this field instead of zero: an FEM model of the part (3D-TSV .TSV, "
                                  "grid or mesh .npz) or a reconstruction directory; it chooses the fringe order "
                                  "that dense fringes leave ambiguous (docs/reconstruction.md, \"A start\")")
    reconstruct.add_argument("--allow-aliased", action="store_true",
                             help="reconstruct a dataset whose fringes are denser than the pixels in over 10%% of "
                                  "the specimen (refused otherwise: their phase is lost; the result is marked)")
    reconstruct.add_argument("--no-truth", action="store_true", help="no ground-truth errors (real captures)")
    reconstruct.add_argument("--restart", action="store_true", help="ignore a checkpoint in the output directory")
    reconstruct.add_argument("--no-progress", action="store_true", help="no progress bar")

    acquire = commands.add_parser("acquire", help="capture a dataset on the polariscope rig (or its digital twin); "
                                                  "rerun the same command to resume an interrupted capture")
    acquire.add_argument("rig", help="rig file (TOML), or a shipped one by name (rig_twin)")
    acquire.add_argument("-o", "--output", required=True, help="dataset directory (journal, frames, rotations)")
    acquire.add_argument("--calibration", help="calibration JSON from mi-nest calibrate (default: the rig file's "
                         "'calibration')")
    acquire.add_argument("--dry-run", action="store_true", help="print the schedule and its estimated duration")
    acquire.add_argument("--yes", action="store_true", help="do not wait for the operator at the manual QWP1")
    acquire.add_argument("--quiet", action="store_true", help="no progress bar")
    acquire.add_argument("--unverified-handedness", action="store_true",
                         help="capture although the calibration has no verified handedness (mi-nest calibrate's "
                              "check on a specimen of known stress); the dataset records it as unverified")

    calibrate = commands.add_parser("calibrate", help="fit the polariscope's angle offsets and retardances from a "
                                                      "free-space sweep on the rig (no specimen in view), then check "
                                                      "its handedness on a specimen of known stress")
    calibrate.add_argument("rig", help="rig file (TOML), or a shipped one by name (rig_twin)")
    calibrate.add_argument("-o", "--output", required=True, help="calibration JSON to write")
    calibrate.add_argument("--yes", action="store_true", help="do not wait for the operator at the manual QWP1")
    calibrate.add_argument("--skip-handedness", action="store_true",
                           help="no specimen of known stress at hand: skip the handedness check; the calibration "
                                "then records it as unverified and acquire needs --unverified-handedness")

    turntable = commands.add_parser("turntable", help="a full turn of a scene or a reconstruction about the "
                                                      "camera's up axis, as an animated GIF (or MP4)")
    turntable.add_argument("source", help="scene XML file or shipped name, or a reconstruction directory")
    turntable.add_argument("-o", "--output", required=True, help="animation path: .gif, or .mp4 (video extra)")
    turntable.add_argument("--frames", type=int, default=36, help="frames per turn (default: 36)")
    turntable.add_argument("--elevation", type=float, default=0.0, help="degrees (default: 0)")
    turntable.add_argument("--fps", type=float, default=12.0, help="frames per second (default: 12)")
    turntable.add_argument("--channel", default="Y", help="channel shown (default: Y, the polariscope's image)")
    turntable.add_argument("--spp", type=int, help="samples per pixel (overrides the scene)")
    _add_polariscope_options(turntable)
    turntable.add_argument("-D", dest="defines", action="append", type=parse_define, default=[],
                           metavar="NAME=VALUE", help="fill the scene's $NAME default (repeatable)")

    compare = commands.add_parser("compare", help="a reconstruction's held-out views beside what its dataset "
                                                  "captured there (PNG)")
    compare.add_argument("result", help="reconstruction directory (output of mi-nest reconstruct)")
    compare.add_argument("-o", "--output", required=True, help="PNG path")
    compare.add_argument("--views", type=int, default=6, help="held-out rotations shown (default: 6)")
    compare.add_argument("--channel", help="measurement shown (default: the dataset's first)")

    principal = commands.add_parser(
        "principal", help="principal stresses and von Mises on a plane, with direction glyphs (PNG); for a "
                          "reconstruction of simulated data also the truth and the error; with its trust map, "
                          "the uncertainty")
    principal.add_argument("source", help="scene XML file or shipped name, or a reconstruction directory")
    principal.add_argument("--plane", help="the plane across an axis: x=MM, y=MM or z=MM")
    principal.add_argument("--normal", help="or the plane's normal X,Y,Z (with --offset)")
    principal.add_argument("--offset", type=float, help="with --normal: the plane's distance from the origin (mm)")
    principal.add_argument("-o", "--output", required=True, help="PNG path")
    principal.add_argument("--res", type=int, default=128, help="pixels along the part's longer side (default: 128)")
    principal.add_argument("-D", dest="defines", action="append", type=parse_define, default=[],
                           metavar="NAME=VALUE", help="fill the scene's $NAME default (repeatable)")

    separate = commands.add_parser(
        "separate", help="the full stress tensor: the mean stress a deviatoric field implies by equilibrium and its "
                         "free surfaces (full.npz, separation.json, separation.png)")
    separate.add_argument("source", help="a reconstruction directory, or a scene XML file or shipped name (its own "
                                         "field's deviator)")
    separate.add_argument("-o", "--output", required=True, help="output directory")
    separate.add_argument("--loaded", action="append", default=[], metavar="box:X0,Y0,Z0,X1,Y1,Z1|mesh:PATH",
                          help="a region where the part is loaded (a box in mm, or the inside of a closed surface "
                               "mesh), besides the scene's own contacts and pressures: no traction condition there "
                               "(repeatable)")
    separate.add_argument("--no-scene-loads", action="store_true",
                          help="take no loaded regions from the scene's stress model (only --loaded ones)")
    separate.add_argument("--resolution", type=int, help="nodes along the part's longest side (default: a "
                                                         "reconstruction grid's own, else 64)")
    separate.add_argument("-D", dest="defines", action="append", type=parse_define, default=[],
                          metavar="NAME=VALUE", help="fill the scene's $NAME default (repeatable)")

    spread = commands.add_parser("spread", help="the seed spread of two or more reconstructions of one dataset "
                                                "(runs with other --option seed=N): each one's trust map gains it "
                                                "and its uncertainty counts it")
    spread.add_argument("results", nargs="+", help="reconstruction directories (mi-nest reconstruct -o) of one dataset")

    view = commands.add_parser("view", help="an interactive viewer in the browser: drag to turn the part; the "
                                            "slice, polariscope, load and wavelength on sliders (Ctrl-C stops it)")
    view.add_argument("source", help="scene XML file or shipped name, or a reconstruction directory")
    view.add_argument("--host", default="127.0.0.1",
                      help="address to serve on (default: 127.0.0.1, this machine only)")
    view.add_argument("--port", type=int, default=8080, help="port (default: 8080, or the next free one)")
    view.add_argument("--res", type=int, default=256, help="frame resolution at rest (default: 256)")
    view.add_argument("--moving-res", type=int, default=128, help="while the view moves (default: 128)")
    view.add_argument("--no-browser", action="store_true", help="do not open a browser")
    view.add_argument("-D", dest="defines", action="append", type=parse_define, default=[],
                      metavar="NAME=VALUE", help="fill the scene's $NAME default (repeatable)")

    slicing = commands.add_parser(
        "slice", help="the fringes of a virtual slice: a slab cut out of the part (stress frozen), seen at normal "
                      "incidence, with its isochromatic order and isoclinic angle maps",
        description="SOURCE is a scene (its true field) or the result directory of mi-nest reconstruct (its "
                    "field in the scene it was reconstructed with). The camera looks back along the normal.")
    slicing.add_argument("source", help="scene XML file or shipped name, or a reconstruction directory")
    slicing.add_argument("--plane", help="the slab's mid-plane across an axis: x=MM, y=MM or z=MM")
    slicing.add_argument("--normal", help="or the mid-plane's normal X,Y,Z (with --offset)")
    slicing.add_argument("--offset", type=float, help="with --normal: the mid-plane's distance from the origin (mm)")
    slicing.add_argument("--thickness", type=float, required=True, help="slab thickness (mm)")
    slicing.add_argument("--region", help="keep only the part of the volume inside: " + REGION_HELP)
    slicing.add_argument("-o", "--output", required=True, help="output EXR (every channel of a render, "
                                                                  "isoclinic.angle, slab.mask)")
    slicing.add_argument("--png", help="also write a PNG of the fringes (in colour with --white-light)")
    slicing.add_argument("--white-light", action="store_true",
                         help="in a white LED's light: the slice's isochromatics in colour (docs/physics.md section 9)")
    slicing.add_argument("--maps", help="also write a PNG of the fringes, isochromatic order and isoclinic angle")
    slicing.add_argument("--res", type=int, default=256, help="pixels along the part's longer side (default: 256)")
    _add_polariscope_options(slicing)
    slicing.add_argument("-D", dest="defines", action="append", type=parse_define, default=[],
                         metavar="NAME=VALUE", help="fill the scene's $NAME default (repeatable)")

    commands.add_parser("scenes", help="list the shipped scenes")
    return parser


def _add_polariscope_options(parser):
    parser.add_argument("--polariscope", choices=POLARISCOPE_KINDS,
                        help="circular or linear (plane: shows isoclinics); any of these three options replaces "
                             "the scene's polariscope (default: circular, dark, 0)")
    parser.add_argument("--field", choices=POLARISCOPE_FIELDS, help="dark or light")
    parser.add_argument("--angle", type=float,
                        help="the polariscope turned by this many degrees: analyser at ANGLE in the dark field")
    parser.add_argument("--load-scale", type=float, default=1.0, help="the stress times this (default: 1)")
    parser.add_argument("--wavelength", type=float, help="nm (default: the material's)")


def _render(args):
    from .views import open_source
    from .views.novel import render_view
    from .io.exr import require_exr_name
    from .render import scene_bands, scene_light, white_light
    source = open_source(args.scene, dict(args.defines))
    _refuse_overwriting_source({"-o": args.output, "--png": args.png}, args.scene, source)
    require_exr_name(args.output)
    light = white_light() if args.white_light else None
    bands = None
    if light is None and args.wavelength is None:      # the scene's own light and camera
        bands = scene_bands(source.scene)
        light = scene_light(source.scene) if bands is None else None
    render_view(source, args.azimuth, args.elevation, _polariscope(args), args.load_scale, args.wavelength,
                spp=args.spp, seed=args.seed, progress=not args.quiet, light=light,
                bands=bands).write(args.output, args.png)


def _refuse_overwriting_source(outputs, text, source):
    """Refuse ``outputs`` (option -> path) that are files ``source`` (opened from ``text``) was read from: its
    scene's, and a reconstruction's own."""
    from .views.source import RESULT_FILES
    from .io.atomic import refuse_overwriting_inputs
    from .scene import scene_inputs, scene_origin
    scene, defines = scene_origin(source.scene)
    results = [Path(text) / name for name in RESULT_FILES] if source.is_reconstruction else []
    refuse_overwriting_inputs(outputs, [*scene_inputs(scene, **defines), *results])


def _polariscope(args):
    """The textbook polariscope the options name, or None (the scene's) when none is given."""
    from .physics.polariscope import polariscope_setting
    if args.polariscope is None and args.field is None and args.angle is None:
        return None
    return polariscope_setting(args.polariscope or "circular", args.field or "dark", args.angle or 0.0)


def _turntable(args):
    from .views import open_source
    from .views.novel import require_animation_path, turntable, write_animation
    require_animation_path(args.output)     # before anything renders
    source = open_source(args.source, dict(args.defines))
    _refuse_overwriting_source({"-o": args.output}, args.source, source)
    images = turntable(source, args.frames, args.elevation, args.channel, _polariscope(args), args.load_scale,
                       args.wavelength, spp=args.spp, progress=True)
    # Intensities go from 0 to 1; any other channel is shown up to its largest value.
    high = 1.0 if args.channel == "Y" or args.channel.startswith("pol.") else max(float(np.max(images)), 1e-6)
    print(f"wrote {write_animation(args.output, images, args.fps, high=high).resolve()} ({len(images)} frames)")


def _compare(args):
    from .views import open_source
    from .views.novel import held_out_views, write_held_out_sheet
    source = open_source(args.result)
    _refuse_overwriting_source({"-o": args.output}, args.result, source)
    if args.views < 1:
        raise ValueError(f"--views must be at least 1, got {args.views}")
    views = held_out_views(source, args.views, args.channel)
    path = write_held_out_sheet(args.output, views, f"{Path(args.result).name}: held-out rotations, "
                                f"{args.channel or 'first channel'} (captured above, rendered below)")
    ratios = [view[3] for view in views]
    print(f"wrote {path.resolve()} ({len(views)} held-out rotations; PSNR of the 16 measurements over the "
          f"specimen {min(ratios):.1f} to {max(ratios):.1f} dB, mean {np.mean(ratios):.2f} dB)")


def _demo(args):
    run_demo(args.output_dir, args.iterations)


def _export(args):
    from .fields.sources import SUPPORTED, export_file, is_stress_file, stress_file
    from .io import export_format
    from .io.atomic import refuse_overwriting_inputs
    export_format(args.output)          # refused before a scene is loaded
    suffix = Path(args.field).suffix
    if not is_stress_file(args.field) and not Path(args.field).is_dir() and suffix.lower() not in ("", ".xml"):
        raise ValueError(f"{args.field}: mi-nest export takes a stress file ({SUPPORTED}), a scene (.xml file or "
                         f"shipped name) or a reconstruction directory, not a '{suffix}' file (a mesh holds no stress: "
                         "solve it with mi-nest fem MESH --fix WHERE --load WHERE:FX,FY,FZ -o part.npz and export "
                         "part.npz)")
    if is_stress_file(args.field):
        refuse_overwriting_inputs({"-o": args.output}, [stress_file(args.field)])
        summary = export_file(stress_file(args.field), args.output, args.resolution)
        print(f"wrote {Path(args.output).resolve()} ({summary})")
        return
    from .export import export_scene
    from .views import open_source
    source = open_source(args.field, dict(args.defines))
    _refuse_overwriting_source({"-o": args.output}, args.field, source)
    if source.deviatoric:
        print(f"{args.field}: the reconstruction's deviatoric stress, written as deviatoric_stress and s_1..s_3 "
              "(photoelasticity does not see the mean stress; the principal directions and von Mises are the "
              "full stress's)")
    if source.trust is not None:
        names = ", ".join(f"trust_{name}" for name in source.trust.terms())
        print(f"{args.field}: its trust map "
              + (f"written beside it as {names}" if Path(args.output).suffix.lower() == ".vtu"
                 else "is not written: 3D-TSV holds stress only (export to .vtu to have it)"))
    for path in export_scene(source.scene, args.output, args.resolution, source.field, source.deviatoric,
                             None if source.trust is None else source.trust.point_data):
        print(f"wrote {path.resolve()}")


def _fem(args):
    import dataclasses
    from .fem import FemError, load_spec, spec_from_flags
    from .io.atomic import refuse_overwriting_inputs
    if (args.spec is None) == (args.mesh is None):
        raise FemError("give either --spec FILE or a MESH with --fix/--load/--pressure")
    refuse_overwriting_inputs({"-o": args.output}, [args.spec or args.mesh])
    if args.spec is not None:
        spec = load_spec(args.spec)
    else:
        try:
            material = tuple(float(v) for v in args.material.split(","))
        except ValueError:
            material = ()
        if len(material) != 2:
            raise FemError(f"--material: expected E,NU, got '{args.material}'")
        spec = spec_from_flags(args.mesh, args.fix, args.load, args.pressure, material, args.order or 1,
                               args.element_size)
    if args.order is not None:
        spec = dataclasses.replace(spec, element_order=args.order)
    result = spec.run()
    result.save(args.output)
    print(result.summary())
    print(f"wrote {Path(args.output).resolve()} ({result.report.nodes} nodes, {result.report.tets} tets)")


def _bench(args):
    from .bench import CASES, run_accuracy, write_results
    names = tuple(args.scenes.split(",")) if args.scenes else tuple(CASES)
    unknown = [n for n in names if n not in CASES]
    if unknown:
        raise ValueError(f"unknown bench case(s) {unknown}; available: {sorted(CASES)}")
    for path in write_results(run_accuracy(names, args.res), args.output_dir):
        print(f"wrote {Path(path).resolve()}")


def _simulate(args):
    from .dataset import CameraModel, SimulationSettings, simulate
    from .io.atomic import refuse_overwriting_inputs
    from .scene import scene_inputs
    refuse_overwriting_inputs({"-o": args.output}, scene_inputs(args.scene, **dict(args.defines)))
    camera = CameraModel(read_noise=args.noise, full_well=args.full_well, bits=args.bits, mosaic=args.mosaic,
                         seed=args.seed)
    settings = SimulationSettings(azimuths=args.azimuth, elevations=args.elevation, azimuth_range=args.azimuth_range,
                                  elevation_range=args.elevation_range, res=args.res, spp=args.spp,
                                  test_fraction=args.test_fraction, camera=camera, half=not args.float,
                                  bands=args.bands)
    report = simulate(args.scene, args.output, settings, defines=args.defines, cluster=_cluster(args))
    print(report.describe())
    print(f"wrote {Path(args.output).resolve()}")


def _cluster(args):
    """The cluster ``--scheduler`` and ``--workers`` ask for; None: this process."""
    from .cluster import ClusterConfig
    if args.scheduler is None:
        if args.workers is not None:
            raise ValueError("--workers sets the processes of a local cluster: add --scheduler local")
        return None
    return ClusterConfig(args.scheduler, args.workers)


def _sweep(args):
    from .sweep import read_sweep, run_sweep
    from .cluster import LOCAL, ClusterConfig
    sweep = read_sweep(args.file, _argument_problem)
    workers = args.workers if args.workers is not None or args.scheduler != LOCAL else 1
    rows = run_sweep(sweep, args.output, ClusterConfig(args.scheduler, workers), progress=not args.no_progress)
    for row in rows:
        error = row.get("deviatoric_error")
        print(f"{row['case']}: " + (f"{100 * error:.1f}% in {row['iterations']} iterations" if row["status"] == "done"
                                    and error is not None else row["status"]))
    print(f"wrote {Path(args.output).resolve()} (sweep.csv, sweep.png, cases/)")
    failed = [row for row in rows if row["status"] != "done"]
    if failed:
        raise ValueError(f"{len(failed)} of {len(rows)} case(s) failed, the first {failed[0]['case']}: "
                         f"{failed[0]['status'].removeprefix('failed: ')}; each case's log is in "
                         f"{args.output}/cases/CASE/log.txt; run the same command again to retry them")


def _argument_problem(arguments: list[str]) -> str | None:
    """What the command-line parser finds wrong with ``arguments`` (None: nothing), in its own words."""
    import contextlib
    import io
    said = io.StringIO()
    try:
        with contextlib.redirect_stderr(said):
            _parser().parse_args(arguments)
    except SystemExit:
        errors = [line for line in said.getvalue().splitlines() if "error: " in line]
        return errors[-1].split("error: ", 1)[1] if errors else said.getvalue().strip()
    return None


def _show(args):
    if Path(args.dataset).is_file():
        _show_mesh(Path(args.dataset), args.output)
        return
    from .dataset import Dataset
    from .dataset.sheet import write_contact_sheet
    from .io.atomic import refuse_overwriting_inputs
    dataset = Dataset(args.dataset, allow_incomplete=True)
    refuse_overwriting_inputs({"-o": args.output}, [dataset.directory / "dataset.json",
                                                    *(dataset.directory / r["file"] for r in dataset.rotations)])
    channel = args.channel or next(name for name in dataset.channels if name.endswith("pol.45.0.0"))
    if channel not in dataset.channels:
        raise ValueError(f"unknown channel '{channel}'; the dataset has {list(dataset.channels)}")
    output = Path(args.output or Path(args.dataset) / "contact_sheet.png")
    write_contact_sheet(output, dataset, channel)
    print(f"{dataset}")
    print(f"wrote {output.resolve()}")


def _show_mesh(path, output):
    """Preview PNG of a mesh stress file: surface by von Mises stress, node forces as arrows, fixed nodes."""
    from .fields.sources import SUPPORTED, is_mesh_file, is_stress_file, load_mesh
    from .io.atomic import refuse_overwriting_inputs
    from .io.preview import write_mesh_preview
    refuse_overwriting_inputs({"-o": output}, [path])
    if not is_stress_file(path):
        raise ValueError(f"{path}: mi-nest show takes a dataset directory or a mesh stress file ({SUPPORTED})")
    if not is_mesh_file(path):
        raise ValueError(f"{path} is a stress grid; mi-nest show previews mesh stress files (export the grid "
                         "with mi-nest export to view it in ParaView)")
    mesh = load_mesh(path)
    output = Path(output or f"{path.stem}_preview.png")
    summary = f"{len(mesh.nodes)} nodes, {len(mesh.tets)} tetrahedra"
    conditions = mesh.boundary.describe() if mesh.boundary is not None else "no boundary conditions in the file"
    write_mesh_preview(output, mesh.nodes, mesh.surface, mesh.stress, mesh.boundary,
                       f"{path.name}: {summary}\n{conditions}")
    print(f"{path.name}: {summary}; {conditions}")
    print(f"wrote {output.resolve()}")


def _reconstruct(args):
    from . import load_scene
    from .dataset import Dataset
    from .io.lock import locked_directory
    from .reconstruct import CheckpointError, optimize
    from .reconstruct.outputs import write_test_view
    from .physics.aliasing import unresolved_dataset
    dataset = Dataset(args.dataset)
    problem = unresolved_dataset(dataset.index.get("fringe_aliasing"), args.dataset)
    if problem and not args.allow_aliased:
        raise ValueError(f"{problem}; or pass --allow-aliased to reconstruct it anyway (the result is marked)")
    scene_file, defines = _reconstruction_scene(args, dataset)
    options = _reconstruction_options(args)
    scene = load_scene(scene_file, **defines)
    with locked_directory(args.output):     # the test view too: no other run between the result and it
        try:
            result = optimize(scene, dataset, output=args.output, resume=not args.restart,
                              progress=not args.no_progress, truth=None if args.no_truth else "scene", **options)
        except CheckpointError as error:
            raise ValueError(f"{error.problem}; add --restart to start over") from None
        print(result.describe())
        written = write_test_view(scene, result, args.output, dataset)
    print(f"wrote {Path(args.output).resolve()} (field.npz, reconstruction.json, trust.npz{written})")


def _reconstruction_scene(args, dataset):
    """The scene file and defines to reconstruct with: ``--scene`` and ``-D``, or the dataset's own."""
    source = dataset.index.get("source", {})
    scene_file = args.scene or source.get("scene")
    if scene_file is None:
        raise ValueError(f"{args.dataset} does not name its scene; give --scene")
    return scene_file, {**(source.get("defines", {}) if args.scene is None else {}), **dict(args.defines)}


def _reconstruction_options(args):
    """``optimize``'s options from the flags given."""
    from .reconstruct import FAST_OPTIONS, NO_REGULARISER, option_value
    fast = dict(FAST_OPTIONS) if args.fast else {}
    if args.no_regulariser:
        fast.pop("average_last", None)      # --fast's averaging is a part of the regulariser left out
    if args.minutes is not None:
        fast.pop("iterations", None)        # the clock ends the run, not --fast's iteration count
    options = {**fast, "kind": args.kind, **({"regulariser": NO_REGULARISER} if args.no_regulariser else {}),
               **({"deterministic": True} if args.deterministic else {})}
    for name, text in args.options:
        options[name.replace("-", "_")] = option_value(name.replace("-", "_"), text)
    for name in ("iterations", "resolution", "method", "start"):
        if getattr(args, name) is not None:
            options[name] = getattr(args, name)
    if args.minutes is not None:
        if not 0 < args.minutes < math.inf:
            raise ValueError(f"--minutes must be a positive number of minutes, got {args.minutes:g}")
        options["time_limit"] = 60.0 * args.minutes
        options.setdefault("iterations", UNBOUNDED_ITERATIONS)
    return options


def _acquire(args):
    from .io.atomic import refuse_overwriting_inputs
    from .rig import acquire as acquisition
    from .rig.config import load
    config = load(args.rig)
    refuse_overwriting_inputs({"-o": args.output}, [config.source])
    if args.calibration is not None:
        config = replace(config, calibration=Path(args.calibration))
        config.calibrated_optics()      # a missing or foreign file is refused before anything moves
    if args.dry_run:
        acquisition.dry_run(config)
        return
    operator = acquisition.unattended_operator if args.yes else acquisition.terminal_operator
    report = acquisition.acquire(config, args.output, operator=operator, progress=not args.quiet,
                                 unverified_handedness=args.unverified_handedness)
    print(report.describe())
    print(f"wrote {Path(args.output).resolve()}")


def _calibrate(args):
    import json
    from .io.atomic import atomic_path, refuse_overwriting_inputs
    from .rig import acquire as acquisition
    from .rig.config import load
    config = load(args.rig)
    refuse_overwriting_inputs({"-o": args.output}, [config.source])
    operator = acquisition.unattended_operator if args.yes else acquisition.terminal_operator
    calibration = acquisition.calibrate(config, operator=operator, check_handedness=not args.skip_handedness)
    print(calibration.describe())
    with atomic_path(args.output, ".json") as tmp:
        Path(tmp).write_text(json.dumps(calibration.to_dict(), indent=1))
    print(f"wrote {Path(args.output).resolve()}")


def _slice(args):
    from .views import Plane, Region, SliceSpec, open_source, slice_render, slice_render_white_light
    from .views.plots import write_slice_maps
    from .io.exr import require_exr_name
    from .physics.polariscope import polariscope_setting
    from .render import scene_light, white_light
    spec = SliceSpec(Plane.parse(args.plane, args.normal, args.offset), args.thickness,
                     None if args.region is None else Region.parse(args.region), args.res,
                     _polariscope(args) or polariscope_setting(), args.load_scale, args.wavelength)
    source = open_source(args.source, dict(args.defines))
    _refuse_overwriting_source({"-o": args.output, "--png": args.png, "--maps": args.maps}, args.source, source)
    require_exr_name(args.output)
    if args.white_light and args.maps:
        raise ValueError("--maps draws one wavelength's isochromatic order and isoclinic angle: leave out "
                         "--white-light or --maps")
    light = white_light() if args.white_light else None
    if light is None and not args.maps and args.wavelength is None:     # the scene's own light
        light = scene_light(source.scene)
    if light is not None:
        result = slice_render_white_light(source.scene, spec, source.field, light)
    else:
        result = slice_render(source.scene, spec, source.field)
    result.write(args.output, args.png)
    if args.maps:
        scope = f"{args.field or 'dark'}-field {args.polariscope or 'circular'} polariscope"
        title = f"{Path(args.source).name}: {spec.describe()}, {scope}"
        print(f"wrote {write_slice_maps(args.maps, result, title).resolve()}")


def _principal(args):
    from .views import Plane, open_source
    from .views.principal import (deviatoric_error, source_slices, uncertainty_on, uncertainty_ranking,
                                   write_principal_figure)
    plane = Plane.parse(args.plane, args.normal, args.offset)
    source = open_source(args.source, dict(args.defines))
    _refuse_overwriting_source({"-o": args.output}, args.source, source)
    shown, truth = source_slices(source, plane, args.res)
    uncertainty = None if source.trust is None else uncertainty_on(shown, source.trust)
    kind = "deviatoric principal stresses" if shown.deviatoric else "principal stresses"
    path = write_principal_figure(args.output, shown, truth, f"{Path(args.source).name}: {kind} at "
                                                             f"{plane.describe()}", uncertainty)
    prefix = "deviatoric s" if shown.deviatoric else "sigma"
    labels = {"sigma_1": f"{prefix}_1", "sigma_3": f"{prefix}_3", "von_mises": "von Mises", "mean": "mean stress"}
    print(f"{Path(args.source).name} at {plane.describe()}: " + ", ".join(
        f"{labels[name]} {np.nanmin(shown.quantity(name)):.3g} to {np.nanmax(shown.quantity(name)):.3g} MPa"
        for name in labels if name in shown.quantities))
    if truth is not None:
        errors = shown.minus(truth)
        for name in ("von_mises", "mean"):
            if name in errors:
                print(f"{labels[name]} against the truth: RMS error {np.sqrt(np.nanmean(errors[name] ** 2)):.3g} MPa "
                      f"(truth's RMS {np.sqrt(np.nanmean(truth.quantity(name) ** 2)):.3g} MPa)")
    if uncertainty is not None:
        print(f"where to trust it (trust.npz): uncertainty {np.nanmin(uncertainty):.3g} to "
              f"{np.nanmax(uncertainty):.3g} stress scales per box length on this plane" + ("" if truth is None else
              f"; it ranks the actual deviatoric error at Spearman "
              f"{uncertainty_ranking(uncertainty, deviatoric_error(shown, truth)):.2f}"))
    print(f"wrote {path.resolve()}")


def _separate(args):
    import contextlib

    from .views import open_source
    from .io.lock import locked_directory
    from .reconstruct.checkpoints import record_separation
    from .scene import scene_field
    from .separation import FULL_FILE, parse_region, separate
    from .separation.regions import suspect_line
    regions = [parse_region(text) for text in args.loaded]          # before the scene loads
    source = open_source(args.source, dict(args.defines))
    output = Path(args.output)
    _refuse_overwriting_source({"-o": output / FULL_FILE}, args.source, source)
    truth = source.truth() if source.is_reconstruction or source.full else source
    # A reconstruction records its separations: no run may rewrite it meanwhile.
    held = locked_directory(args.source) if source.deviatoric else contextlib.nullcontext()
    with locked_directory(output), held:
        result = separate(source.field, source.scene, regions, args.resolution, model_loads=not args.no_scene_loads)
        record = {"source": str(Path(args.source).resolve()) if Path(args.source).exists() else args.source,
                  "defines": dict(args.defines)}
        written = result.write(output, record, None if truth is None else truth.field or scene_field(truth.scene),
                               f"{Path(args.source).name}: mean stress by equilibrium")
        summary = result.summary
        if source.deviatoric:
            record_separation(args.source, {"output": str(output.resolve()), "loaded": summary["loaded"],
                                            "residual": summary["residual"], "grid": summary["grid"],
                                            "suspect_loads": len(summary["suspect_loads"])})
    loaded = summary["loaded"]
    print(f"{Path(args.source).name}: mean stress separated on a {'x'.join(map(str, summary['grid']))} grid in "
          f"{summary['seconds']:.1f} s; {100 * loaded['free_share']:.1f}% of the surface free "
          f"({100 * loaded['by_model']:.1f}% loaded by the scene's model, {100 * loaded['by_regions']:.1f}% by "
          f"--loaded); traction left on the free surface {summary['residual']['free_surface_per_scale']:.3g} "
          "stress scales (RMS)")
    if not loaded["by_model"] and not regions:
        warnings.warn("no loaded region: every surface is taken as free (give --loaded where the part is held or "
                      "pushed)")
    for patch in summary["suspect_loads"][:SUSPECTS_SHOWN]:
        warnings.warn(suspect_line(patch))
    if len(summary["suspect_loads"]) > SUSPECTS_SHOWN:
        warnings.warn(f"{len(summary['suspect_loads']) - SUSPECTS_SHOWN} smaller such patches are listed in "
                      f"{written[1]} (suspect_loads)")
    for kind, label in (("all", "inside the part"), ("away_from_loads", "away from the loaded regions")):
        if kind in summary.get("against_truth", {}):
            e = summary["against_truth"][kind]
            print(f"against the truth, {label}: full tensor {100 * e['full']:.2f}%, deviator "
                  f"{100 * e['deviatoric']:.2f}%, mean stress {100 * e['mean_per_scale']:.2f}% of the stress scale")
    for path in written:
        print(f"wrote {path.resolve()}")


def _spread(args):
    from .reconstruct.spread import write_seed_spread
    for written in write_seed_spread(args.results):
        summary = written.summary
        ranking = "" if written.ranking is None else \
            (f"; it ranks the actual deviatoric error at Spearman {written.ranking[0]:.2f} ({written.ranking[1]:.2f} "
             "without the spread)")
        print(f"{written.directory}: seed spread over {len(summary['seed_spread_from'])} other run(s): median "
              f"{summary['seed_spread_median']:.3g} MPa, 95th percentile {summary['seed_spread_p95']:.3g} MPa; "
              f"uncertainty median {summary['uncertainty_median']:.3g}, 95th percentile "
              f"{summary['uncertainty_p95']:.3g} stress scales per box length{ranking}")
        print(f"wrote {(written.directory / 'trust.npz').resolve()} and reconstruction.json")


# The largest patches of free surface left carrying traction that a separation prints (the rest: separation.json).
SUSPECTS_SHOWN = 3


def _view(args):
    from .arguments import whole_number
    from .views.viewer import PORTS, require_address, run_viewer
    for name in ("res", "moving_res"):
        whole_number(f"--{name.replace('_', '-')}", getattr(args, name), minimum=8)
    whole_number("--port", args.port, minimum=PORTS.start, maximum=PORTS.stop - 1)
    require_address(args.host, args.port)       # before the scene loads
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        warnings.warn(f"serving on {args.host}: anyone who can reach this machine there can see the viewer")
    run_viewer(args.source, dict(args.defines), args.host, args.port, args.res, args.moving_res,
               open_browser=not args.no_browser)


def _scenes(args):
    from . import scene_path
    for path in sorted(scene_path(DEFAULT_SCENE).parent.glob("*.xml")):
        print(path.stem)


COMMANDS = {"render": _render, "demo": _demo, "export": _export, "fem": _fem, "bench": _bench,
            "simulate": _simulate, "sweep": _sweep, "show": _show, "reconstruct": _reconstruct, "acquire": _acquire,
            "calibrate": _calibrate, "scenes": _scenes, "slice": _slice,
            "turntable": _turntable, "compare": _compare, "principal": _principal,
            "separate": _separate, "spread": _spread, "view": _view}
# The options naming a file that a command writes, with the suffix of an example name: one naming a directory is
# refused before any work (a file cannot replace it).
FILE_OUTPUTS = {"render": (("-o", "output", ".exr"), ("--png", "png", ".png")),
                "slice": (("-o", "output", ".exr"), ("--png", "png", ".png"), ("--maps", "maps", ".png")),
                "principal": (("-o", "output", ".png"),), "compare": (("-o", "output", ".png"),),
                "show": (("-o", "output", ".png"),), "turntable": (("-o", "output", ".gif"),),
                "export": (("-o", "output", ".vtu"),), "fem": (("-o", "output", ".npz"),),
                "calibrate": (("-o", "output", ".json"),)}
# What makes each command's work smaller when it runs out of memory.
SMALLER = {"render": "lower the resolution (-D res=N) or --spp", "simulate": "lower --res or --spp",
           "turntable": "lower the resolution (-D res=N) or --spp", "export": "lower --resolution",
           "slice": "lower --res", "principal": "lower --res", "view": "lower --res and --moving-res",
           "reconstruct": "lower --option batch_size (or pixel_samples)"}


def _format_warning(message, category, filename, lineno, line=None):
    return f"mi-nest: warning: {message}\n"


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    status = None
    try:
        with interrupts.handling():
            status = _run(args)
    except KeyboardInterrupt:
        # Python runs a signal's handler at its next bytecode, which can be after the run's own handling (the
        # handler being restored, or a second press): the run is over either way, and says so once.
        status = status if status == INTERRUPTED_STATUS else _interrupted(args.command)
    if status == INTERRUPTED_STATUS:
        signal.signal(signal.SIGINT, signal.SIG_IGN)     # the process ends now: no traceback from a late Ctrl-C
    return status


def _run(args):
    formatwarning, warnings.formatwarning = warnings.formatwarning, _format_warning
    try:
        if args.variant is not None:
            variants.use(args.variant)
        variants.require_usable()
        for option, name, suffix in FILE_OUTPUTS.get(args.command, ()):
            if getattr(args, name) is not None:
                require_file_path(getattr(args, name), option, suffix)
        COMMANDS[args.command](args)
    except KeyboardInterrupt as interrupt:
        return _interrupted(args.command, interrupt)
    except (ValueError, OSError, RigError, DivergenceError) as error:
        if interrupts.received():
            return _interrupted(args.command)
        print(f"mi-nest: error: {error}", file=sys.stderr)
        return 2
    except MemoryError as error:
        # What no estimate refused up front; NumPy's says how much it wanted.
        print(f"mi-nest: error: out of memory{f' ({error})' if str(error) else ''}: "
              f"{SMALLER.get(args.command, 'make the work smaller')}, or free some memory", file=sys.stderr)
        return 2
    except Exception:
        # Ctrl-C inside a Dr.Jit or Mitsuba callback comes out as their own error.
        if interrupts.received():
            return _interrupted(args.command)
        raise
    finally:
        warnings.formatwarning = formatwarning
    return 0


# What an interrupted run of these commands kept, beyond what the interruption itself says.
KEPT_WHEN_INTERRUPTED = {"simulate": "the rotations written so far are kept: run the same command again to resume",
                         "acquire": "every journaled frame is kept: run the same command again to resume",
                         "sweep": "the finished cases are kept: run the same command again to run the others"}
# The shell's exit status for a process ended by SIGINT (128 + 2).
INTERRUPTED_STATUS = 130


def _interrupted(command, interrupt=None):
    detail = str(interrupt or "") or KEPT_WHEN_INTERRUPTED.get(command)
    print("mi-nest: interrupted" + (f"; {detail}" if detail else ""), file=sys.stderr)
    return INTERRUPTED_STATUS


if __name__ == "__main__":
    sys.exit(main())
