"""One band against three: how far several wavelengths push the fringe density a reconstruction survives.

Issue 37's experiment. Over a sweep of loads on the disk (and of the kitten's fringe value), each load is
simulated three ways with the same total number of measurements (images) and the same seeds and read noise
(0.01), then reconstructed by ``mi-nest reconstruct DATA -o OUT --minutes BUDGET --allow-aliased`` with the
defaults, the same budget for each, once per optimiser seed (``--option seed=N``: at 6 x 6 views one run
can end on a wrong branch that another escapes, so a single run says little):

- ``one band``: 532 nm, ``--azimuth 6 --elevation 6`` (36 views of 16 measurements);
- ``three narrow bands``: 450, 532 and 650 nm (lasers or interference filters), 4 x 3 views of 48;
- ``one band, 4 x 3 views``: the control, the three-band arms' views in one band (a third of the images): what
  the views alone change;
- ``RGB camera``: a colour camera's red, green and blue under the white LED (``--bands rgb``), 4 x 3 views of 48,
  simulated at 28 wavelengths (10 nm apart) and traced every 20 nm (14: ``--option spectral_step=20``; at all 28
  an iteration costs 73 ms against 42, and 16 for one band: the budget would buy a quarter of the iterations).

Prints and writes (``experiments/results/bands.csv`` and ``bands.png``: relative deviatoric error against the
one-band data's share of aliased pixels, the median over seeds and their range, a line per arm) the error,
held-out PSNR and iterations of each run, with the CPU. Every finished run is written at once: an interrupted
sweep keeps what it did, a rerun skips it.

    python benchmarks/bands.py                       # the disk, 3 loads x 4 arms x 3 seeds, 1.5 min each (65 min)
    python benchmarks/bands.py --scene kitten        # the kitten's fringe values
    python benchmarks/bands.py --levels 300 --seeds 0 --minutes 0.1 --res 16    # a smoke run
"""
from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from accuracy_suite import HERE, NOISE, SEED, read_rows, run_command, write_rows
from reconstruction import cpu_name


@dataclass(frozen=True)
class Arm:
    """How a load is recorded (its bands, None: one wavelength, the scene's; its rotations) and reconstructed
    (``reconstruct``'s own options)."""
    name: str
    bands: str | None
    azimuths: int
    elevations: int
    options: tuple = ()


ARMS = (Arm("one band", None, 6, 6), Arm("three narrow bands", "450,532,650", 4, 3),
        Arm("RGB camera", "rgb", 4, 3, ("--option", "spectral_step=20")),
        Arm("one band, 4 x 3 views", None, 4, 3))
# Per scene: the define swept, its levels (sparse to dense fringes) and the defines every level shares.
SWEEPS = {"disk_compression": ("load", (100, 300, 600), {"contact_width": 4}),
          "kitten": ("fringe_value", (4500, 2250, 1500), {})}


def simulate(scene: str, defines: dict, arm: Arm, data: Path, res: int) -> float:
    bands = [] if arm.bands is None else ["--bands", arm.bands]
    return run_command("simulate", [scene, "-o", str(data), "--azimuth", str(arm.azimuths), "--elevation",
                                    str(arm.elevations), "--res", str(res), "--noise", str(NOISE), "--seed",
                                    str(SEED), *(f"-D{k}={v}" for k, v in defines.items()), *bands])


def reconstruct(data: Path, output: Path, minutes: float, options: tuple, seed: int) -> dict:
    wall = run_command("reconstruct", [str(data), "-o", str(output), "--minutes", f"{minutes:g}", "--restart",
                                       "--allow-aliased", "--no-progress", "--option", "track_error_every=50",
                                       "--option", f"seed={seed}", *options])
    return {"wall": wall, "record": json.loads((output / "reconstruction.json").read_text())}


def aliased_share(data: Path) -> float:
    """The share of the specimen's pixels where the data's fringes are denser than its pixels (the mean over
    views; a dataset of bands reports its shortest wavelength's)."""
    summary = json.loads((data / "dataset.json").read_text()).get("fringe_aliasing") or {}
    return float(summary.get("mean_fraction", 0.0))


def chart(rows: list[dict], sweep: str, path: Path, title: str) -> None:
    """Error against the one-band data's aliased share: per arm the median over seeds, bars from the best to the
    worst."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    figure, axis = plt.subplots(figsize=(7, 4.5))
    for arm in ARMS:
        cells = per_level(rows, arm)
        if not cells:
            continue
        x = [aliased for aliased, _ in cells.values()]
        errors = [np.array(values) for _, values in cells.values()]
        median = [float(np.median(e)) for e in errors]
        spread = [[m - e.min() for m, e in zip(median, errors)], [e.max() - m for m, e in zip(median, errors)]]
        views = "" if "views" in arm.name else f", {arm.azimuths} x {arm.elevations} views"
        axis.errorbar(x, median, yerr=spread, fmt="o-", capsize=3, label=arm.name + views)
        for xi, yi, level in zip(x, median, cells):
            axis.annotate(f"{sweep} {level}", (xi, yi), fontsize=6, textcoords="offset points", xytext=(3, 3))
    axis.set(xlabel="share of the specimen's pixels whose fringes alias (one band, 532 nm)",
             ylabel="relative deviatoric stress error", yscale="log", title=title)
    axis.axhline(0.15, color="grey", lw=0.6, ls="--")
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def per_level(rows: list[dict], arm: Arm) -> dict[str, tuple[float, list[float]]]:
    """``{level: (the one-band data's aliased share, the errors of its seeds)}`` of ``arm``, by level."""
    cells = {}
    for row in rows:
        if row["arm"] == arm.name:
            cells.setdefault(str(row["level"]), (float(row["one_band_aliased"]), []))[1].append(
                float(row["deviatoric_error"]))
    return dict(sorted(cells.items(), key=lambda item: item[1][0]))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="disk_compression", choices=sorted(SWEEPS))
    parser.add_argument("--levels", help="comma-separated levels of the swept define (default: the sweep's)")
    parser.add_argument("--seeds", default="0,1,2", help="optimiser seeds, comma-separated (default: 0,1,2)")
    parser.add_argument("--minutes", type=float, default=1.5, help="optimisation budget per run")
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
    seeds = [int(x) for x in args.seeds.split(",")]
    label = "bands" if args.scene == "disk_compression" else f"bands_{args.scene}"
    path = args.results / f"{label}.csv"
    rows = read_rows(path)

    def key(row):
        return tuple(str(row[k]) for k in ("level", "arm", "seed", "res", "budget_min"))
    done = set() if args.again else {key(r) for r in rows}
    print(f"CPU: {cpu_name()}; {args.scene}, {sweep} {levels}, seeds {seeds}, {args.res} px, {args.minutes:g} min "
          "per run", flush=True)
    for level in levels:
        defines = {**shared, sweep: level}
        case = args.data / f"{args.scene}_{sweep}{level}_{args.res}"
        one_band = case / ARMS[0].name / "data"
        for arm in ARMS:
            for seed in seeds:
                identity = {"level": level, "arm": arm.name, "seed": seed, "res": args.res,
                            "budget_min": round(args.minutes, 3)}
                if key(identity) in done:
                    print(f"{sweep} {level}, {arm.name}, seed {seed}: in {path.name} already (--again reruns it)",
                          flush=True)
                    continue
                data = case / arm.name / "data"
                try:
                    simulated = simulate(args.scene, defines, arm, data, args.res)
                    if not (one_band / "dataset.json").is_file():
                        simulate(args.scene, defines, ARMS[0], one_band, args.res)
                    run = reconstruct(data, case / arm.name / f"seed{seed}", args.minutes, arm.options, seed)
                except RuntimeError as error:
                    print(f"{sweep} {level}, {arm.name}, seed {seed}: {error}", flush=True)
                    continue
                metrics = run["record"]["metrics"]
                row = {"scene": args.scene, "sweep": sweep, **identity, "bands": arm.bands or "532 nm",
                       "views": f"{arm.azimuths}x{arm.elevations}",
                       "images": arm.azimuths * arm.elevations * (16 if arm.bands is None else 48),
                       "options": " ".join(arm.options), "simulate_s": round(simulated, 1),
                       "reconstruct_s": round(run["wall"], 1), "iterations": len(run["record"]["history"]),
                       "deviatoric_error": round(metrics.get("deviatoric_error", float("nan")), 4),
                       "test_psnr": round(metrics.get("test_psnr", float("nan")), 2),
                       "one_band_aliased": round(aliased_share(one_band), 4), "cpu": cpu_name()}
                rows = [r for r in rows if key(r) != key(row)] + [row]
                write_rows(rows, path)
                print(f"{sweep} {level}, {arm.name}, seed {seed}: {100 * row['deviatoric_error']:.1f}% "
                      f"({row['iterations']} iterations in {row['reconstruct_s']} s; one band aliased in "
                      f"{100 * row['one_band_aliased']:.0f}% of the pixels)", flush=True)
    if rows:
        chart(rows, sweep, args.results / f"{label}.png",
              f"{args.scene}: one band or three, same images and {args.minutes:g} min\n{cpu_name()}")
        print("median over seeds (best to worst):")
        print("| " + " | ".join(["level", "aliased (one band)"] + [arm.name for arm in ARMS]) + " |")
        print("|---|---:|" + "---:|" * len(ARMS))
        cells = {arm.name: per_level(rows, arm) for arm in ARMS}
        for level in (str(x) for x in levels):
            aliased = next((c[level][0] for c in cells.values() if level in c), float("nan"))
            shown = []
            for arm in ARMS:
                errors = cells[arm.name].get(level, (0.0, []))[1]
                shown.append(f"{100 * np.median(errors):.1f}% ({100 * min(errors):.1f} to {100 * max(errors):.1f})"
                             if errors else "")
            print(f"| {sweep} {level} | {100 * aliased:.0f}% | " + " | ".join(shown) + " |")


if __name__ == "__main__":
    main()
