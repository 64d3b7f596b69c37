"""The ``mi-nest`` command line: argument handling only, the work lives in the package."""
from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

DEFAULT_SCENE = "disk_compression"


def _definition(text):
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got '{text}'")
    return name, value


def _parser():
    parser = argparse.ArgumentParser(prog="mi-nest", description="Photoelastic stress tomography in Mitsuba 3.")
    commands = parser.add_subparsers(dest="command", required=True)

    render = commands.add_parser("render", help="render a scene to a multichannel EXR")
    render.add_argument("scene", help="scene XML file, or the name of a shipped scene")
    render.add_argument("-o", "--output", required=True, help="output EXR path")
    render.add_argument("-D", dest="defines", action="append", type=_definition, default=[],
                        metavar="NAME=VALUE", help="fill the scene's $NAME default (repeatable)")
    render.add_argument("--png", help="also write a PNG preview of the main channel")
    render.add_argument("--spp", type=int, help="samples per pixel (overrides the scene)")
    render.add_argument("--seed", type=int, default=0, help="random seed")
    render.add_argument("--quiet", action="store_true", help="no progress bar")

    demo = commands.add_parser("demo", help="render the default scene (disk under diametral compression)")
    demo.add_argument("-o", "--output-dir", default="mi_nest_out", help="where to write (default: mi_nest_out)")

    export = commands.add_parser("export", help="write a stress field as VTK (.vtu) for ParaView")
    export.add_argument("field", help="stress file (grid or mesh .npz, 3D-TSV .stress), or a scene "
                                      "(XML file or shipped name) whose specimens are sampled on grids")
    export.add_argument("-o", "--output", required=True, help="output .vtu path")
    export.add_argument("-D", dest="defines", action="append", type=_definition, default=[],
                        metavar="NAME=VALUE", help="fill a scene's $NAME default (repeatable)")
    export.add_argument("--resolution", type=int, default=64,
                        help="grid nodes along the longest axis when sampling (default: 64)")

    fem = commands.add_parser(
        "fem", help="solve a linear-elastic FEM model and write its nodal stress (.npz)",
        description="Either --spec FILE (TOML/JSON: geometry, material, loads, fixtures), or a MESH "
                    "(a volume mesh meshio reads, or a closed surface meshed with the gmsh extra) with "
                    "--fix/--load/--pressure. WHERE is x=<v>, y=<v>, z=<v> (a plane) or a surface group "
                    "name of the mesh file.")
    fem.add_argument("mesh", nargs="?", help="volume mesh or closed surface file")
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
    simulate.add_argument("--seed", type=int, default=0, help="noise seed (default: 0)")
    simulate.add_argument("--test-fraction", type=float, default=0.2, help="rotations held out (default: 0.2)")
    simulate.add_argument("--float", action="store_true", help="store float32 instead of half floats")
    simulate.add_argument("-D", dest="defines", action="append", default=[], type=_definition, metavar="NAME=VALUE",
                          help="set a scene $parameter")

    show = commands.add_parser("show", help="contact sheet PNG of a dataset")
    show.add_argument("dataset", help="dataset directory")
    show.add_argument("-c", "--channel", default="pol.45.0.0", help="channel to tile (default: pol.45.0.0)")
    show.add_argument("-o", "--output", help="PNG path (default: DATASET/contact_sheet.png)")

    commands.add_parser("scenes", help="list the shipped scenes")
    return parser


def _render(scene_file, output, defines, png=None, spp=None, seed=0, progress=True):
    from . import load_scene, render
    scene = load_scene(scene_file, **dict(defines))
    result = render(scene, spp=spp, seed=seed, progress=progress)
    result.write_exr(output)
    print(f"wrote {Path(output).resolve()} ({len(result.channels)} channels, {result.main.shape[1]}x{result.main.shape[0]}, "
          f"{result.seconds:.2f} s)")
    if png:
        result.write_png(png)
        print(f"wrote {Path(png).resolve()}")
    return scene, result


def _demo(output_dir):
    from . import scene_path
    out = Path(output_dir)
    scene, result = _render(scene_path(DEFAULT_SCENE), out / f"{DEFAULT_SCENE}.exr", [],
                            png=out / f"{DEFAULT_SCENE}.png")
    medium = scene.shapes()[0].interior_medium()
    disk = medium.field
    order = 8 * disk.load / (math.pi * disk.diameter * medium.fringe_value)
    print(f"disk under diametral compression, dark-field circular polariscope: closed-form fringe order "
          f"at the centre {order:.3f}; main channel in [{result.main.min():.3f}, {result.main.max():.3f}]")
    return result


def _export(field, output, defines, resolution):
    from .fields.sources import SUFFIXES, export_vtu
    if Path(field).suffix in SUFFIXES:
        summary = export_vtu(field, output, resolution)
        print(f"wrote {Path(output).resolve()} ({summary})")
        return
    from . import load_scene
    from .export import export_scene_vtu
    for path in export_scene_vtu(load_scene(field, **dict(defines)), output, resolution):
        print(f"wrote {path.resolve()}")


def _fem(args):
    import dataclasses
    from .fem import FemError, load_spec, spec_from_flags
    if (args.spec is None) == (args.mesh is None):
        raise FemError("give either --spec FILE or a MESH with --fix/--load/--pressure")
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


def _bench_accuracy(scenes, res, output_dir):
    from .bench import CASES, run_accuracy, write_results
    names = tuple(scenes.split(",")) if scenes else tuple(CASES)
    unknown = [n for n in names if n not in CASES]
    if unknown:
        raise ValueError(f"unknown bench case(s) {unknown}; available: {sorted(CASES)}")
    for path in write_results(run_accuracy(names, res), output_dir):
        print(f"wrote {Path(path).resolve()}")


def _simulate(args):
    from .dataset import CameraModel, SimulationSettings, simulate
    camera = CameraModel(read_noise=args.noise, full_well=args.full_well, bits=args.bits, mosaic=args.mosaic,
                         seed=args.seed)
    settings = SimulationSettings(azimuths=args.azimuth, elevations=args.elevation, azimuth_range=args.azimuth_range,
                                  elevation_range=args.elevation_range, res=args.res, spp=args.spp,
                                  test_fraction=args.test_fraction, camera=camera, half=not args.float)
    report = simulate(args.scene, args.output, settings, defines=args.defines)
    print(report.describe())
    print(f"wrote {Path(args.output).resolve()}")


def _show(args):
    from .dataset import Dataset
    from .dataset.sheet import write_contact_sheet
    dataset = Dataset(args.dataset, allow_incomplete=True)
    if args.channel not in dataset.channels:
        raise ValueError(f"unknown channel '{args.channel}'; the dataset has {list(dataset.channels)}")
    output = Path(args.output or Path(args.dataset) / "contact_sheet.png")
    write_contact_sheet(output, dataset, args.channel)
    print(f"{dataset}")
    print(f"wrote {output.resolve()}")


def _format_warning(message, category, filename, lineno, line=None):
    return f"mi-nest: warning: {message}\n"


def main(argv=None):
    args = _parser().parse_args(argv)
    formatwarning, warnings.formatwarning = warnings.formatwarning, _format_warning
    try:
        if args.command == "render":
            _render(args.scene, args.output, args.defines, png=args.png, spp=args.spp, seed=args.seed,
                    progress=not args.quiet)
        elif args.command == "demo":
            _demo(args.output_dir)
        elif args.command == "export":
            _export(args.field, args.output, args.defines, args.resolution)
        elif args.command == "fem":
            _fem(args)
        elif args.command == "bench":
            _bench_accuracy(args.scenes, args.res, args.output_dir)
        elif args.command == "simulate":
            _simulate(args)
        elif args.command == "show":
            _show(args)
        elif args.command == "scenes":
            from . import scene_path
            for path in sorted(scene_path(DEFAULT_SCENE).parent.glob("*.xml")):
                print(path.stem)
    except (ValueError, OSError) as error:
        print(f"mi-nest: error: {error}", file=sys.stderr)
        return 2
    finally:
        warnings.formatwarning = formatwarning
    return 0


if __name__ == "__main__":
    sys.exit(main())
