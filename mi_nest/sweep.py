"""``mi-nest sweep SWEEP.toml -o OUT``: many cases (simulate, reconstruct, evaluate) as tasks on Dask.

A sweep file names a base scene, the settings of its datasets and of their reconstructions, and the values to
vary; every combination of those values is a case::

    scene = "disk_compression"

    [scene_parameters]          # the scene's $parameters (-D NAME=VALUE)
    contact_width = 4

    [simulate]                  # mi-nest simulate's options, by their long names
    azimuth = 8
    elevation = 8
    res = 32
    noise = 0.01

    [reconstruct]               # mi-nest reconstruct's options; option = {...} for --option NAME=VALUE
    minutes = 1
    allow_aliased = true
    option = { batch_size = 512 }

    [vary]                      # each a list of values: scene.NAME, simulate.NAME, reconstruct.NAME,
    "scene.load" = [100, 300]   # reconstruct.option.NAME
    "reconstruct.option.seed" = [0, 1]

Cases that are not a product (the accuracy suite's) are listed instead, each a table of the same names with one
value, and optionally its own ``scene`` and ``name``; each listed case is crossed with ``[vary]``::

    [[cases]]
    name = "dense"
    "scene.load" = 300

Each case runs ``mi-nest simulate`` and ``mi-nest reconstruct`` as a user would, in a process of its own on a
worker, into ``OUT/cases/<case>/``; its log goes beside them. A finished case is not run again; a failed one is
reported with its error and run again by the next sweep, the others going on. The results gather in
``OUT/sweep.csv`` and ``OUT/sweep.png`` (error against each varied value and against time).
"""
from __future__ import annotations

import csv
import itertools
import json
import math
import re
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import mitsuba as mi

from .cluster import Cluster, ClusterConfig, cluster_for
from .io.atomic import atomic_path
from .io.lock import locked_directory
from .io.toml import read_toml
from .scene import SceneError, scene_defaults, scene_file, scene_inputs

SECTIONS = ("scene", "scene_parameters", "simulate", "reconstruct", "vary", "cases")
# A listed case's keys besides the varied names.
CASE_KEYS = ("name", "scene")
# What a varied name may start with, and the section it changes.
VARIED = {"scene": "scene_parameters", "simulate": "simulate", "reconstruct": "reconstruct"}
RESULTS, CHART, ROW = "sweep.csv", "sweep.png", "row.json"


class SweepError(ValueError):
    """A sweep file that cannot run: said before any case starts."""


class CaseFailed(RuntimeError):
    """One of a case's commands failed; the message is its last line."""


@dataclass(frozen=True)
class Case:
    """One combination of the varied values and the two commands that make it."""
    name: str
    values: dict                 # varied name -> value
    simulate: list[str]          # mi-nest simulate's arguments, without -o
    reconstruct: list[str]       # mi-nest reconstruct's, without the dataset and -o

    def commands(self) -> list[list[str]]:
        """What the case runs, as its finished row records it: a case edited since is not the one on disk."""
        return [self.simulate, self.reconstruct]


@dataclass(frozen=True)
class Sweep:
    source: Path
    columns: list[str]           # every name a case sets: the listed cases' and the varied ones
    varied: list[str]            # the [vary] names
    cases: list[Case]
    listed: bool                 # whether the file lists its cases ([[cases]])


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _arguments(options: dict) -> list[str]:
    """A section's options as command-line arguments: ``true`` a bare flag, ``false`` none, ``option`` a table of
    ``--option NAME=VALUE``."""
    arguments = []
    for name, value in options.items():
        if name == "option":
            for key, setting in value.items():
                arguments += ["--option", f"{key}={json.dumps(setting) if isinstance(setting, bool) else setting}"]
        elif value is True:
            arguments.append(_flag(name))
        elif value is not False:
            arguments += [_flag(name), str(value)]
    return arguments


def _case_name(entry: dict, varied: dict) -> str:
    """A case's directory: a listed case's name (or its values), then the varied values, as ``name=value``."""
    def named(values):
        return [f"{name.rsplit('.', 1)[-1]}={value}" for name, value in values.items() if name not in CASE_KEYS]
    listed = [str(entry["name"])] if "name" in entry else named(entry)
    return re.sub(r"[^\w.=,-]+", "-", "_".join([*listed, *named(varied)]) or "base")


def read_sweep(path: str | Path, check: Callable[[list[str]], str | None]) -> Sweep:
    """The cases of sweep file ``path``; ``check(arguments)`` says what is wrong with a command line (None:
    nothing), as the command-line parser reads it. Raises :class:`SweepError` naming the file and what to fix."""
    path = Path(path)
    try:
        spec = read_toml(path, "sweep file")
    except ValueError as error:
        raise SweepError(str(error)) from None
    unknown = sorted(set(spec) - set(SECTIONS))
    if unknown:
        raise SweepError(f"{path}: unknown section(s) {unknown}; a sweep file has {list(SECTIONS)}")
    scene = _base_scene(spec.get("scene"), path)
    vary = spec.get("vary", {})
    for name, values in vary.items():
        _check_varied(name, path)
        if not isinstance(values, list) or not values:
            raise SweepError(f"{path}: '{name}' must list at least one value, such as [100, 300]")
    listed = spec.get("cases", [{}])
    if not isinstance(listed, list) or not listed or not all(isinstance(entry, dict) for entry in listed):
        raise SweepError(f"{path}: list the cases as [[cases]] tables")
    for entry in listed:
        for name, value in entry.items():
            if name not in CASE_KEYS:
                _check_varied(name, path)
            if isinstance(value, (list, dict)):
                raise SweepError(f"{path}: a listed case gives '{name}' one value, not {value!r} (lists go in [vary])")
    cases = [_case(spec, _base_scene(entry["scene"], path) if "scene" in entry else scene, entry,
                   dict(zip(vary, combination)), path, check)
             for entry in listed for combination in itertools.product(*vary.values())]
    names = [case.name for case in cases]
    if len(set(names)) < len(names):
        twice = sorted({name for name in names if names.count(name) > 1})
        raise SweepError(f"{path}: cases {twice} would share a directory: give the varied values distinct texts, "
                         "or the listed cases names")
    columns = list(dict.fromkeys([*(k for entry in listed for k in entry if k != "name"), *vary]))
    return Sweep(path, columns, list(vary), cases, "cases" in spec)


def _check_varied(name: str, path: Path) -> None:
    head = name.split(".", 1)[0]
    if head not in VARIED or "." not in name:
        raise SweepError(f"{path}: cannot vary '{name}': name scene.PARAMETER, simulate.OPTION, "
                         "reconstruct.OPTION or reconstruct.option.NAME")


def _base_scene(scene, path: Path) -> str:
    """A sweep's or a listed case's scene: a shipped name, or an XML file relative to the sweep file."""
    if not isinstance(scene, str):
        raise SweepError(f"{path}: name the base scene: scene = \"disk_compression\" (a shipped name or an XML file)")
    if not Path(scene).is_absolute() and Path(scene).suffix == ".xml":
        scene = str((path.parent / scene).resolve())
    try:
        scene_file(scene)
    except (SceneError, OSError, ValueError) as error:
        raise SweepError(f"{path}: {error}") from None
    return scene


def _case(spec: dict, scene: str, entry: dict, varied: dict, path: Path,
          check: Callable[[list[str]], str | None]) -> Case:
    """The case of listed ``entry`` (one value per name, its own scene and name) crossed with the ``varied``
    values: the sweep's sections with them put in, checked as the commands."""
    values = {**{k: v for k, v in entry.items() if k not in CASE_KEYS}, **varied}
    sections = {key: dict(spec.get(key, {})) for key in ("scene_parameters", "simulate", "reconstruct")}
    if "option" in sections["reconstruct"]:      # a copy per case: the varied options go into it
        sections["reconstruct"]["option"] = dict(sections["reconstruct"]["option"])
    for name, value in values.items():
        head, rest = name.split(".", 1)
        if head == "reconstruct" and rest.startswith("option."):
            sections["reconstruct"].setdefault("option", {})[rest[len("option."):]] = value
        else:
            sections[VARIED[head]][rest] = value
    name = _case_name(entry, varied)
    if "scene" in entry:
        values = {"scene": entry["scene"], **values}
    try:
        scene_inputs(scene, **sections["scene_parameters"])
    except SceneError as error:
        raise SweepError(f"{path}: case {name}: {_unused_parameter(str(error), scene)}") from None
    defines = [a for k, v in sections["scene_parameters"].items() for a in ("-D", f"{k}={v}")]
    simulate = [scene, *_arguments(sections["simulate"]), *defines]
    reconstruct = _arguments(sections["reconstruct"])
    for command, arguments in (("simulate", [*simulate, "-o", "DATA"]),
                               ("reconstruct", ["DATA", "-o", "OUT", *reconstruct])):
        problem = check([command, *arguments])
        if problem:
            raise SweepError(f"{path}: case {name}: mi-nest {command}: {problem}")
    return Case(name, values, simulate, reconstruct)


def _unused_parameter(message: str, scene: str) -> str:
    found = re.search(r"unused parameters:\s*-?\s*\$(\w+)", message)
    if not found:
        return message
    known = sorted({name for file in scene_inputs(scene) if file.suffix == ".xml" for name in scene_defaults(file)})
    return f"the scene has no parameter '{found.group(1)}'; its parameters are {', '.join(known)}"


# The process a case's commands run in: Dr.Jit on the worker's share of the cores, then the command line.
_COMMAND = ("import sys, drjit as dr; threads = int(sys.argv[1]); threads and dr.set_thread_count(threads); "
            "from mi_nest.cli import main; sys.exit(main(sys.argv[2:]))")


def _run(arguments: list[str], log: Path, threads: int | None) -> None:
    """``mi-nest ARGUMENTS`` in a process of its own, its output appended to ``log``; :class:`CaseFailed` with its
    last line if it fails."""
    with log.open("a") as out:
        out.write(f"$ mi-nest {' '.join(arguments)}\n")
        out.flush()
        done = subprocess.run([sys.executable, "-c", _COMMAND, str(threads or 0), *arguments], stdout=out,
                              stderr=subprocess.STDOUT, preexec_fn=_end_with_parent)
    if done.returncode != 0:
        lines = [line for line in log.read_text().splitlines() if line.strip()]
        raise CaseFailed(lines[-1].removeprefix("mi-nest: error: ") if lines
                         else f"mi-nest {arguments[0]} exited with {done.returncode}")


def _end_with_parent():
    """Linux: the case's process ends with the worker that started it (a killed worker leaves no orphan)."""
    try:
        import ctypes
        import signal
        ctypes.CDLL("libc.so.6").prctl(1, signal.SIGTERM)       # PR_SET_PDEATHSIG
    except OSError:
        pass


def run_case(case: Case, directory: Path, threads: int | None, variant: str) -> dict:
    """On a worker: simulate, reconstruct and evaluate ``case`` in ``directory``; its row (written as ``row.json``
    when it is done, which marks it finished; a failed case's row says why in its status). Its commands run on
    the sweep's Mitsuba ``variant``."""
    directory.mkdir(parents=True, exist_ok=True)
    log = directory / "log.txt"
    start = time.perf_counter()
    try:
        _run(["--variant", variant, "simulate", *case.simulate, "-o", str(directory / "data")], log, threads)
        simulated = time.perf_counter()
        _run(["--variant", variant, "reconstruct", str(directory / "data"), "-o", str(directory / "result"),
              "--no-progress", *case.reconstruct], log, threads)
    except CaseFailed as failure:
        return {"case": case.name, **case.values, "status": f"failed: {failure}"}
    record = json.loads((directory / "result" / "reconstruction.json").read_text())
    metrics = record["metrics"]
    row = {"case": case.name, **case.values, "status": "done", "commands": case.commands(),
           "deviatoric_error": metrics.get("deviatoric_error"), "test_psnr": metrics.get("test_psnr"),
           "iterations": len(record["history"]), "optimise_s": round(record["seconds"], 1),
           "simulate_s": round(simulated - start, 1), "reconstruct_s": round(time.perf_counter() - simulated, 1)}
    with atomic_path(directory / ROW, ".json") as temporary:
        Path(temporary).write_text(json.dumps(row))
    return row


def finished_row(directory: Path) -> dict | None:
    try:
        return json.loads((directory / ROW).read_text())
    except (OSError, ValueError):
        return None


def run_sweep(sweep: Sweep, output: str | Path, cluster: ClusterConfig | Cluster,
              progress: bool = True, say: Callable[[str], None] = print) -> list[dict]:
    """Run the cases of ``sweep`` not finished in ``output`` on ``cluster``; every case's row (failed ones with
    their error), also written to ``sweep.csv`` and drawn in ``sweep.png``."""
    from tqdm import tqdm
    output = Path(output)
    with locked_directory(output):
        rows = {}
        todo = []
        for case in sweep.cases:
            row = finished_row(output / "cases" / case.name)
            if row is None:
                todo.append(case)
            elif row.get("commands") != case.commands():
                raise SweepError(f"{output / 'cases' / case.name} was run with other settings than {sweep.source} "
                                 "gives it now; choose a new directory, or delete that case to run it again")
            else:
                rows[case.name] = row
        say(f"sweep: {len(sweep.cases)} case(s), {len(rows)} finished before, {len(todo)} to run")
        bar = tqdm(total=len(sweep.cases), initial=len(rows), desc="sweep", unit="case", disable=not progress)
        try:
            with bar, cluster_for(cluster, bool(todo), say=bar.write) as connected:
                if connected is not None:
                    _run_cases(connected, todo, output, rows, bar)
        finally:
            ordered = [rows[case.name] for case in sweep.cases if case.name in rows]
            write_results(ordered, sweep, output)
    return ordered


def _run_cases(cluster: Cluster, cases: Sequence[Case], output: Path, rows: dict, bar) -> None:
    from distributed import as_completed
    client = cluster.client
    futures = {client.submit(run_case, case, output / "cases" / case.name, cluster.drjit_threads, mi.variant(),
                             pure=False,
                             key=f"mi_nest-case-{case.name}-{time.time_ns()}"): case for case in cases}
    try:
        for future in as_completed(futures):
            case = futures[future]
            try:
                rows[case.name] = future.result()
            except Exception as error:      # a case that broke its worker is reported too; the others go on
                rows[case.name] = {"case": case.name, **case.values,
                                   "status": f"failed: {type(error).__name__}: {error}"}
            bar.update()
    except BaseException:
        client.cancel(list(futures))
        raise


COLUMNS = ("deviatoric_error", "test_psnr", "iterations", "optimise_s", "simulate_s", "reconstruct_s")


def write_results(rows: list[dict], sweep: Sweep, output: Path) -> None:
    """``sweep.csv`` (a row per case) and ``sweep.png``: the error of each listed case, against each varied value
    and against the optimisation time."""
    fields = ["case", *sweep.columns, "status", *COLUMNS]
    with atomic_path(output / RESULTS, ".csv") as temporary:
        with open(temporary, "w", newline="") as stream:
            writer = csv.DictWriter(stream, fields, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)
    done = [row for row in rows if row["status"] == "done" and row.get("deviatoric_error") is not None]
    if done:
        _chart(done, ["case"] * sweep.listed + sweep.varied, output / CHART)


def _chart(rows: list[dict], panels: list[str], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    panels = [*panels, "optimise_s"]
    figure, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.6), squeeze=False)
    for axis, name in zip(axes[0], panels):
        values = [row[name] for row in rows]
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)
        labels = sorted(set(map(str, values)), key=[str(v) for v in values].index)
        positions = values if numeric else [labels.index(str(v)) for v in values]
        axis.scatter(positions, [100 * row["deviatoric_error"] for row in rows], s=18)
        if not numeric:
            axis.set_xticks(range(len(labels)), labels, rotation=60 if name == "case" else 30, fontsize=7,
                            ha="right")
        axis.set(xlabel="optimisation time (s)" if name == "optimise_s" else name,
                 ylabel="deviatoric error (%)", ylim=(0, None))
        axis.grid(alpha=0.3)
    figure.suptitle(f"sweep: {len(rows)} finished case(s)")
    figure.tight_layout()
    with atomic_path(path, ".png") as temporary:
        figure.savefig(temporary, dpi=100)
    plt.close(figure)
