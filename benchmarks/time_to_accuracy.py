"""Time to the reconstruction targets: `mi-nest reconstruct DATA -o OUT` of this checkout against another.

For each scene, simulates the target dataset once (32 x 32 rotations at 64 x 64:
the disk at 100 N over 4 mm contacts, the kitten at a fringe value of 4500 N/mm),
then reconstructs it with each version's defaults, the command a user types,
from the same files (``--flags`` adds flags to this checkout's command, e.g.
``--flags=--fast``). Each version runs in its own process from a copy of its
tree laid out as a wheel installs it. The script prints, per run, the
optimisation time (the runs' own clock, which leaves out loading and the final
evaluation), the final deviatoric error against the scene's target, the peak
resident memory and the resident memory at each quarter of the run (growth with
the iterations would show there), and per scene the ratio of the two
optimisation times. It writes ``time_to_accuracy.csv`` and a plot of the error
against the optimisation time to ``--output``.

    git worktree add /tmp/before 04d869c
    python benchmarks/time_to_accuracy.py --baseline /tmp/before --output /tmp/tta --flags=--fast

The runs take minutes each (the baseline's about a quarter of an hour per scene
on 2 cores); run nothing else beside them. ``--rotations`` and ``--iterations``
(given to both versions) shrink them for a quick check, whose times say nothing.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from reconstruction import cpu_name, installed_layout

HERE = Path(__file__).resolve().parents[1]
# Per scene: its defines and the target (relative deviatoric error) of the issue that set it.
SCENES = {"disk": ("disk_compression", {"load": "100", "contact_width": "4"}, 0.05),
          "kitten": ("kitten", {"fringe_value": "4500"}, 0.10)}
CLI = "import sys; from mi_nest.cli import main; sys.exit(main(sys.argv[1:]))"


def simulate(scene: str, defines: dict, directory: Path, rotations: int) -> None:
    """The target dataset, with this checkout (resumed if already there)."""
    command = [sys.executable, "-c", CLI, "simulate", scene, "-o", str(directory), "--azimuth", str(rotations),
               "--elevation", str(rotations), "--res", "64"] + [f"-D{k}={v}" for k, v in defines.items()]
    subprocess.run(command, check=True, cwd=HERE, env={**os.environ, "PYTHONPATH": str(HERE)})


def resident_mib(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def reconstruct(path_entry: Path, data: Path, output: Path, flags: list[str]) -> dict:
    """One version's defaults (and ``flags``) on ``data``, its resident memory sampled every half second."""
    command = [sys.executable, "-c", CLI, "reconstruct", str(data), "-o", str(output), "--restart",
               "--no-progress", "--option", "track_error_every=500", *flags]
    samples = []
    # stderr to a file: a pipe nobody reads during the run would block the child once its buffer fills.
    with tempfile.TemporaryFile("w+") as errors:
        child = subprocess.Popen(command, env={**os.environ, "PYTHONPATH": str(path_entry)}, cwd=path_entry,
                                 stdout=subprocess.DEVNULL, stderr=errors, text=True)
        while child.poll() is None:
            value = resident_mib(child.pid)
            if value is not None:
                samples.append(value)
            time.sleep(0.5)
        if child.returncode != 0:
            errors.seek(0)
            raise SystemExit(f"the run from {path_entry} failed:\n{errors.read()[-3000:]}")
    record = json.loads((output / "reconstruction.json").read_text())
    return {"record": record, "rss": samples}


def quarters(samples: list[float]) -> list[float]:
    """Resident memory at the end of each quarter of the run's samples."""
    if not samples:
        return []
    return [round(samples[min(len(samples) - 1, len(samples) * k // 4)]) for k in (1, 2, 3, 4)]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="another mi_nest checkout (e.g. a git worktree)")
    parser.add_argument("--scenes", default="kitten,disk", help="comma-separated: disk, kitten")
    parser.add_argument("--output", type=Path, default=Path("time_to_accuracy"))
    parser.add_argument("--data", type=Path, help="where the datasets are kept (default: under --output)")
    parser.add_argument("--flags", default="", help="flags added to this checkout's command (e.g. --flags=--fast)")
    parser.add_argument("--rotations", type=int, default=32, help="per axis (default: 32, the targets')")
    parser.add_argument("--iterations", type=int, help="both versions' --iterations (default: their own)")
    args = parser.parse_args()
    names = args.scenes.split(",")
    unknown = sorted(set(names) - set(SCENES))
    if unknown:
        raise SystemExit(f"unknown scene(s) {unknown}; choose from {sorted(SCENES)}")
    args.output.mkdir(parents=True, exist_ok=True)
    data_root = args.data or args.output / "data"
    shrink = ["--iterations", str(args.iterations)] if args.iterations else []
    command = " ".join(["mi-nest reconstruct DATA -o OUT", *shrink])
    print(f"{cpu_name()}; `{command}` (each version's defaults; this checkout's with "
          f"'{args.flags}'), {args.rotations} x {args.rotations} rotations at 64 x 64", flush=True)
    rows, histories, finals = [], {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        versions = {"this checkout": installed_layout(HERE, tmp / "current")}
        if args.baseline:
            versions["baseline"] = installed_layout(args.baseline.resolve(), tmp / "baseline")
        for name in names:
            scene, defines, target = SCENES[name]
            data = data_root / name
            simulate(scene, defines, data, args.rotations)
            seconds = {}
            for version, path_entry in versions.items():
                run = reconstruct(path_entry, data, args.output / "results" / f"{name}_{version.replace(' ', '_')}",
                                  (args.flags.split() if version == "this checkout" else []) + shrink)
                record = run["record"]
                error = record["metrics"]["deviatoric_error"]
                seconds[version] = record["seconds"]
                histories[(name, version)] = [(h["seconds"], h["deviatoric_error"]) for h in record["history"]
                                              if "deviatoric_error" in h]
                finals[(name, version)] = (record["seconds"], error)
                row = {"scene": name, "version": version, "iterations": len(record["history"]),
                       "optimise_s": round(record["seconds"], 1), "deviatoric_error": round(error, 4),
                       "target": target, "met": error < target,
                       "peak_rss_mib": round(max(run["rss"], default=0)),
                       "rss_quarters_mib": " ".join(map(str, quarters(run["rss"])))}
                rows.append(row)
                print(f"{name:7s} {version:14s} {row['iterations']:6d} it  {row['optimise_s']:7.1f} s  "
                      f"error {100 * error:5.2f}% (target {100 * target:.0f}%: {'met' if row['met'] else 'MISSED'})  "
                      f"peak {row['peak_rss_mib']} MiB, by quarter {row['rss_quarters_mib']}", flush=True)
            if len(seconds) == 2:
                ratio = seconds["baseline"] / seconds["this checkout"]
                print(f"{name}: baseline / this checkout optimisation time {ratio:.2f}x", flush=True)
    with open(args.output / "time_to_accuracy.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    plot(histories, finals, args.flags, args.output / "time_to_accuracy.png")


def plot(histories, finals, flags, path):
    """The tracked error of each run's iterates against its clock, and its final result (with iterate
    averaging, below the last iterate) as a dot at its end."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    figure, axes = plt.subplots(figsize=(7, 4.5))
    for key, points in histories.items():
        if points:
            line, = axes.plot(*zip(*points), label=", ".join(key), linestyle="--" if key[1] == "baseline" else "-")
            axes.plot(*finals[key], "o", color=line.get_color())
    for _, _, target in SCENES.values():
        axes.axhline(target, color="grey", linewidth=0.5)
    axes.set(xlabel="optimisation time (s)", ylabel="relative deviatoric error", yscale="log",
             title=f"time to the targets: the baseline's defaults, this checkout's {flags or 'defaults'} "
                   "(dots: final results)")
    axes.legend()
    figure.savefig(path, dpi=120, bbox_inches="tight")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
