"""One band against three: how far several wavelengths push the fringe density a reconstruction survives.

Issue 37's experiment. Over a sweep of loads on the disk (and of the kitten's fringe value), each load is
simulated three ways with the same total number of measurements (images) and the same seeds and read noise
(0.01), then reconstructed by ``mi-nest reconstruct DATA -o OUT --minutes BUDGET --allow-aliased`` with the
defaults, the same budget for each:

- ``one band``: 532 nm, ``--azimuth 6 --elevation 6`` (36 views of 16 measurements);
- ``three narrow bands``: 450, 532 and 650 nm (lasers or interference filters), 4 x 3 views of 48;
- ``RGB camera``: a colour camera's red, green and blue under the white LED (``--bands rgb``), 4 x 3 views of 48.

Prints and writes (``experiments/results/bands.csv`` and ``bands.png``: relative deviatoric error against the
one-band data's share of aliased pixels, a line per arm) the error, held-out PSNR and iterations of each run,
with the CPU. Every finished run is written at once: an interrupted sweep keeps what it did, a rerun skips it.

    python benchmarks/bands.py                       # the disk, 5 loads x 3 arms, 2 minutes each (about 40 min)
    python benchmarks/bands.py --scene kitten        # the kitten's fringe values
    python benchmarks/bands.py --levels 300 --minutes 0.1 --res 16    # a smoke run
"""
from __future__ import annotations

import argparse
import json
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from accuracy_suite import CLI, HERE, NOISE, SEED, read_rows, write_rows
from reconstruction import cpu_name


@dataclass(frozen=True)
class Arm:
    """How a load is recorded: its bands (None: one wavelength, the scene's) and its rotations."""
    name: str
    bands: str | None
    azimuths: int
    elevations: int


ARMS = (Arm("one band", None, 6, 6), Arm("three narrow bands", "450,532,650", 4, 3),
        Arm("RGB camera", "rgb", 4, 3))
# Per scene: the define swept, its levels (sparse to dense fringes) and the defines every level shares.
SWEEPS = {"disk_compression": ("load", (100, 200, 300, 450, 600), {"contact_width": 4}),
          "kitten": ("fringe_value", (4500, 3000, 2000, 1500), {})}


def simulate(scene: str, defines: dict, arm: Arm, data: Path, res: int) -> float:
    start = time.perf_counter()
    command = [*CLI, "simulate", scene, "-o", str(data), "--azimuth", str(arm.azimuths), "--elevation",
               str(arm.elevations), "--res", str(res), "--noise", str(NOISE), "--seed", str(SEED)]
    command += [f"-D{name}={value}" for name, value in defines.items()]
    if arm.bands is not None:
        command += ["--bands", arm.bands]
    done = subprocess.run(command, cwd=HERE, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"simulate failed: {done.stderr.strip().splitlines()[-1]}")
    return time.perf_counter() - start


def reconstruct(data: Path, output: Path, minutes: float) -> dict:
    start = time.perf_counter()
    command = [*CLI, "reconstruct", str(data), "-o", str(output), "--minutes", f"{minutes:g}", "--restart",
               "--allow-aliased", "--no-progress", "--option", "track_error_every=50"]
    done = subprocess.run(command, cwd=HERE, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"reconstruct failed: {done.stderr.strip().splitlines()[-1]}")
    return {"wall": time.perf_counter() - start, "record": json.loads((output / "reconstruction.json").read_text())}


def aliased_share(data: Path) -> float:
    """The share of the specimen's pixels where the data's fringes are denser than its pixels (the mean over
    views; a dataset of bands reports its shortest wavelength's)."""
    summary = json.loads((data / "dataset.json").read_text()).get("fringe_aliasing") or {}
    return float(summary.get("mean_fraction", 0.0))


def chart(rows: list[dict], sweep: str, path: Path, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    figure, axis = plt.subplots(figsize=(7, 4.5))
    for arm in ARMS:
        points = sorted((float(r["one_band_aliased"]), float(r["deviatoric_error"]), r["level"]) for r in rows
                        if r["arm"] == arm.name)
        if points:
            x, y, levels = zip(*points)
            axis.plot(x, y, "o-", label=arm.name)
            for xi, yi, level in zip(x, y, levels):
                axis.annotate(f"{sweep} {level}", (xi, yi), fontsize=6, textcoords="offset points", xytext=(3, 3))
    axis.set(xlabel="share of the specimen's pixels whose fringes alias (one band, 532 nm)",
             ylabel="relative deviatoric stress error", yscale="log", title=title)
    axis.axhline(0.15, color="grey", lw=0.6, ls="--")
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="disk_compression", choices=sorted(SWEEPS))
    parser.add_argument("--levels", help="comma-separated levels of the swept define (default: the sweep's)")
    parser.add_argument("--minutes", type=float, default=2.0, help="optimisation budget per run")
    parser.add_argument("--res", type=int, default=64, help="image width and height")
    parser.add_argument("--data", type=Path, default=HERE / "experiments" / "out" / "bands",
                        help="where datasets and reconstructions are kept")
    parser.add_argument("--results", type=Path, default=HERE / "experiments" / "results",
                        help="where the CSV and the chart go (default: experiments/results, the committed ones)")
    parser.add_argument("--again", action="store_true", help="rerun what the CSV already has")
    args = parser.parse_args()
    sweep, levels, shared = SWEEPS[args.scene]
    if args.levels:
        levels = tuple(float(x) if "." in x else int(x) for x in args.levels.split(","))
    label = "bands" if args.scene == "disk_compression" else f"bands_{args.scene}"
    path = args.results / f"{label}.csv"
    rows = read_rows(path)
    done = set() if args.again else {(r["level"], r["arm"], r["res"], r["budget_min"]) for r in rows}
    print(f"CPU: {cpu_name()}; {args.scene}, {sweep} {levels}, {args.res} px, {args.minutes:g} min per run",
          flush=True)
    for level in levels:
        defines = {**shared, sweep: level}
        one_band = args.data / f"{args.scene}_{sweep}{level}_{args.res}" / "one band" / "data"
        for arm in ARMS:
            key = (str(level), arm.name, str(args.res), str(round(args.minutes, 3)))
            if key in done:
                print(f"{sweep} {level}, {arm.name}: in {path.name} already (--again reruns it)", flush=True)
                continue
            folder = args.data / f"{args.scene}_{sweep}{level}_{args.res}" / arm.name
            try:
                simulated = simulate(args.scene, defines, arm, folder / "data", args.res)
                if arm.bands is not None and not (one_band / "dataset.json").is_file():
                    simulate(args.scene, defines, ARMS[0], one_band, args.res)
                run = reconstruct(folder / "data", folder / "reconstruction", args.minutes)
            except RuntimeError as error:
                print(f"{sweep} {level}, {arm.name}: {error}", flush=True)
                continue
            metrics = run["record"]["metrics"]
            row = {"scene": args.scene, "sweep": sweep, "level": level, "arm": arm.name,
                   "bands": arm.bands or "532 nm", "views": f"{arm.azimuths}x{arm.elevations}",
                   "images": arm.azimuths * arm.elevations * (16 if arm.bands is None else 48), "res": args.res,
                   "budget_min": round(args.minutes, 3), "simulate_s": round(simulated, 1),
                   "reconstruct_s": round(run["wall"], 1), "iterations": len(run["record"]["history"]),
                   "deviatoric_error": round(metrics.get("deviatoric_error", float("nan")), 4),
                   "test_psnr": round(metrics.get("test_psnr", float("nan")), 2),
                   "one_band_aliased": round(aliased_share(one_band), 4), "cpu": cpu_name()}
            rows = [r for r in rows if (r["level"], r["arm"], r["res"], r["budget_min"]) != key] + [row]
            write_rows(rows, path)
            print(f"{sweep} {level}, {arm.name}: {100 * row['deviatoric_error']:.1f}% "
                  f"({row['iterations']} iterations in {row['reconstruct_s']} s; one band aliased in "
                  f"{100 * row['one_band_aliased']:.0f}% of the pixels)", flush=True)
    if rows:
        chart(rows, sweep, args.results / f"{label}.png",
              f"{args.scene}: one band or three, same images and {args.minutes:g} min; {cpu_name()}")
        print("| " + " | ".join(["level"] + [arm.name for arm in ARMS]) + " |")
        print("|---|" + "---:|" * len(ARMS))
        for level in levels:
            cells = []
            for arm in ARMS:
                found = [r for r in rows if str(r["level"]) == str(level) and r["arm"] == arm.name]
                cells.append(f"{100 * float(found[-1]['deviatoric_error']):.1f}%" if found else "")
            print(f"| {sweep} {level} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
