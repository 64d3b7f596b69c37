"""Every ``mi-nest`` command in the README and the user docs runs, as written, at a tiny size.

The commands are read from the documents' ``bash`` blocks and run in order, one document's in one fresh
directory (a recipe's later commands read what its earlier ones wrote), through ``mi_nest.cli.main``. Only the
sizes shrink: resolutions, rotations (written or the default's), frames, iterations (``SHRINK``); every file,
scene and option is the document's. Paths into the checkout (``scenes/...``) resolve against it. A
reconstruction that a recipe takes from the demo (``mi_nest_out/reconstruction``) is made first by a tiny
simulation and reconstruction of the demo's scene. The one command that serves until Ctrl-C, ``mi-nest
view``, is checked for its arguments only: tests/test_viewer.py serves it.
"""
from __future__ import annotations

import json
import re
import shlex
import shutil
import warnings
from contextlib import contextmanager
from pathlib import Path

import pytest

from mi_nest.cli import _parser, main

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]
# Option -> the tiny value it takes here (the document's value otherwise).
SHRINK = {"--res": "16", "--azimuth": "2", "--elevation": "2", "--resolution": "8", "--frames": "2",
          "--views": "1", "--iterations": "3", "--minutes": "0.02", "--moving-res": "8"}
DEFINES = {"res": "16", "grid_resolution": "16", "spp": "1"}
# The scheduler address docs/cluster.md writes for a cluster's; a LocalCluster's here.
DOCUMENTED_SCHEDULER = "tcp://HOST:8786"
# What a tiny reconstruction adds: few rays, a coarse grid, and acceptance of the aliasing tiny images have.
TINY_RECONSTRUCTION = ["--iterations", "3", "--option", "batch_size=64", "--resolution", "6", "--allow-aliased",
                       "--no-progress"]


def commands(document: str) -> list[str]:
    """The ``mi-nest`` command lines of ``document``'s bash blocks, comments dropped, in order."""
    text = (ROOT / document).read_text()
    found = []
    for block in re.findall(r"```(?:bash|sh)\n(.*?)```", text, re.S):
        for line in block.splitlines():
            line = line.split("  #")[0].split(" # ")[0].strip()
            if re.match(r"(\.venv/bin/)?mi-nest ", line):
                found.append(line)
    return found


def tiny(line: str) -> list[str]:
    """The arguments of a documented command line, sizes shrunk."""
    words = shlex.split(line)[1:]
    shrunk = []
    index = 0
    while index < len(words):
        word = words[index]
        if word in SHRINK and index + 1 < len(words):
            shrunk += [word, SHRINK[word]]
            index += 2
            continue
        if word == "-D" and index + 1 < len(words) and words[index + 1].split("=")[0] in DEFINES:
            name = words[index + 1].split("=")[0]
            shrunk += ["-D", f"{name}={DEFINES[name]}"]
            index += 2
            continue
        shrunk.append(word)
        index += 1
    command = shrunk[0]
    if command in ("render", "simulate", "slice", "turntable", "view", "principal") and not any(
            w == "--res" or w.startswith("res=") for w in shrunk):
        shrunk += ["--res", "16"] if command in ("simulate", "slice", "principal", "view") else ["-D", "res=16"]
    if command == "reconstruct":
        shrunk = [w for w in shrunk if w != "--fast"] + TINY_RECONSTRUCTION
    if command == "simulate":
        # The default is 32 x 32 rotations: a thousand renders, even at 16 px.
        shrunk += [w for option in ("--azimuth", "--elevation") if option not in shrunk for w in (option, "2")]
    if command == "turntable" and "--frames" not in shrunk:
        shrunk += ["--frames", "2"]
    if command == "export" and "--resolution" not in shrunk:
        shrunk += ["--resolution", "8"]
    if command == "demo":
        shrunk += ["--iterations", "3"]
    return shrunk


def _demo_reconstruction(directory: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert main(["simulate", "disk_compression", "-o", str(directory / "mi_nest_out" / "dataset"), "--azimuth",
                     "2", "--elevation", "2", "--res", "16", "-D", "load=60", "-D", "contact_width=4"]) == 0
        assert main(["reconstruct", str(directory / "mi_nest_out" / "dataset"), "-o",
                     str(directory / "mi_nest_out" / "reconstruction"), *TINY_RECONSTRUCTION]) == 0


@contextmanager
def _scheduler_for(lines: list[str]):
    """A LocalCluster whose scheduler stands for the documents' ``tcp://HOST:8786`` (its address; None if no
    line names one): the remote path runs as written, against a real scheduler and worker processes."""
    if not any(DOCUMENTED_SCHEDULER in line for line in lines):
        yield None
        return
    from distributed import LocalCluster
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        yield cluster.scheduler_address


@pytest.mark.parametrize("document", [d for d in DOCUMENTS if commands(d)])
def test_every_documented_command_runs(document, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for folder in ("scenes", "experiments"):
        (tmp_path / folder).symlink_to(ROOT / folder)
    lines = commands(document)
    if any("mi_nest_out/" in line for line in lines):
        _demo_reconstruction(tmp_path)
    with _scheduler_for(lines) as scheduler:
        for line in lines:
            _run_documented(document, line.replace(DOCUMENTED_SCHEDULER, scheduler or DOCUMENTED_SCHEDULER), capsys)


def _shrunk_sweep(path: str) -> str:
    """A copy of sweep file ``path`` at the tiny sizes (its scene, parameters, options and varied names kept; the
    first two values of each and the first two listed cases), written into the current directory; its name."""
    import tomllib
    spec = tomllib.loads(Path(path).read_text())
    spec.setdefault("simulate", {}).update(azimuth=2, elevation=2, res=16)
    reconstruct = spec.setdefault("reconstruct", {})
    reconstruct.pop("minutes", None)
    reconstruct.update({"iterations": 3, "resolution": 6, "allow_aliased": True})
    reconstruct.setdefault("option", {})["batch_size"] = 64
    spec["vary"] = {name: values[:2] for name, values in spec.get("vary", {}).items()}
    tiny_sizes = {"simulate.azimuth": 2, "simulate.elevation": 2, "simulate.res": 16}
    cases = [{k: tiny_sizes.get(k, v) for k, v in case.items()} for case in spec.pop("cases", [])[:2]]

    def value(v):
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return "true" if v is True else "false" if v is False else json.dumps(v)

    lines = [f"scene = {value(spec['scene'])}"]
    for section, table in spec.items():
        if isinstance(table, dict):
            lines += [f"[{section}]", *(f"{json.dumps(k)} = {value(v)}" for k, v in table.items())]
    for case in cases:
        lines += ["[[cases]]", *(f"{json.dumps(k)} = {value(v)}" for k, v in case.items())]
    shrunk = Path(f"tiny_{Path(path).name}")
    shrunk.write_text("\n".join(lines) + "\n")
    return str(shrunk)


def _run_documented(document, line, capsys):
    arguments = tiny(line)
    if arguments[0] == "sweep":
        arguments[1] = _shrunk_sweep(arguments[1])
    if arguments[0] == "view":
        _parser().parse_args(arguments)         # serving is tests/test_viewer.py's
        return
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # tiny images alias; said in the output
        code = main(arguments)
    error = capsys.readouterr().err
    assert code == 0, f"{document}: `{line}` (run as `mi-nest {shlex.join(arguments)}`) failed: {error}"


def test_the_shrinking_keeps_every_file_scene_and_option():
    line = (".venv/bin/mi-nest simulate scenes/examples/part.xml -D part=part.npz -D res=512 -o data/part "
            "--azimuth 12 --elevation 12 --res 48")
    assert tiny(line) == ["simulate", "scenes/examples/part.xml", "-D", "part=part.npz", "-D", "res=16", "-o",
                          "data/part", "--azimuth", "2", "--elevation", "2", "--res", "16"]
    assert "--fast" not in tiny("mi-nest reconstruct data/disk -o results/fast --fast")
    assert shutil.which  # the harness needs nothing but the package
