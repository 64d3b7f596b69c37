"""How much partial reflections (ghosts) change the images, against the noise of a real camera: picks max_bounces.

Renders the disk and the kitten (part n = 1.55, in air and in water) from a
few views with ``max_bounces`` 0 (the transmitted path alone) up to 8, at
many samples per pixel, and compares the 16 polariscope channels on the
specimen's pixels: each setting against none (what the ghosts add), and
against the most bounces (``missing_``: what a user loses by stopping
there). The renders share their seed, so that the transmitted path is the
same in each and a difference is the ghosts' alone; their own sampling noise
is measured from a second seed at the most bounces. A change matters where it exceeds what a camera cannot
resolve anyway: one 8-bit level (1/255) and the photon noise of one frame of
a polarisation camera (IMX250MZR: about 10,500 electrons at full scale, so
sqrt(I / 10500) at intensity I). Writes ``ghosts.csv`` and ``ghosts.png``
(the largest ghost image beside its transmitted one)::

    .venv/bin/python experiments/ghosts.py
"""
from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

import common
import mi_nest
from mi_nest.physics import MEASUREMENTS

FULL_WELL = 10_500.0
LEVEL = 1.0 / 255.0
SCENES = {
    "disk_compression": ({"load": 60.0, "contact_width": 4.0},
                         {"axial": ("0, 0, 100", "0, 1, 0"), "30 degrees": ("0, 50, 86.6", "0, 1, 0"),
                          "edge-on": ("100, 0, 0", "0, 1, 0")}),
    "kitten": ({"fringe_value": 4500.0},
               {"front": ("-1.5, -200, 43", "0, 0, 1"), "side": ("200, 0, 43", "0, 0, 1"),
                "above": ("-1.5, -100, 216", "0, 0, 1")}),
}
SURROUNDINGS = {"air": 1.0, "water": 1.33}


def channels(name, defines, bounces, res, spp, seed=0):
    scene = mi_nest.load_scene(name, res=res, spp=spp, ior=1.55, max_bounces=bounces, **defines)
    result = mi_nest.render(scene, seed=seed, progress=False)
    return {key: np.asarray(result.channels[key], dtype=np.float64) for key in list(MEASUREMENTS) + ["path.length"]}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, default=64)
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--bounces", type=int, nargs="+", default=[1, 2, 3, 4, 8])
    parser.add_argument("--output", type=Path, default=Path("experiments/out/ghosts"))
    args = parser.parse_args()
    warnings.simplefilter("ignore", RuntimeWarning)     # the fringe-aliasing report of every render
    rows, worst = [], None
    most = max(args.bounces)
    for name, (scene_defines, views) in SCENES.items():
        for surrounding, ext_ior in SURROUNDINGS.items():
            for view, (origin, up) in views.items():
                defines = {**scene_defines, "ext_ior": ext_ior, "origin": origin, "up": up}
                plain = channels(name, defines, 0, args.res, args.spp)
                renders = {bounces: channels(name, defines, bounces, args.res, args.spp) for bounces in args.bounces}
                # The ghosts' own sampling noise: the same estimate from other seeds.
                other = ghost_difference(channels(name, defines, most, args.res, args.spp, seed=1),
                                         channels(name, defines, 0, args.res, args.spp, seed=1), renders[most], plain)
                for bounces in sorted(args.bounces):
                    row = {"scene": name, "surrounding": surrounding, "view": view, "max_bounces": bounces,
                           **compare(plain, renders[bounces], "", plain),
                           **compare(renders[bounces], renders[most], "missing_", plain)}
                    if bounces == most:
                        row["ghost_noise_p99"] = other
                    rows.append(row)
                    print(row, flush=True)
                    if worst is None or row["max_abs"] > worst[0]["max_abs"]:
                        worst = (row, plain, renders[bounces])
    common.write_table(rows, args.output / "ghosts.csv")
    plot(worst, args.output / "ghosts.png")


def _stack(images, mask):
    return np.stack([images[key] for key in MEASUREMENTS])[:, mask]


def ghost_difference(ghosts_other, plain_other, ghosts, plain):
    """99th percentile (specimen pixels) of the difference between the ghosts' estimates from two seeds: their
    sampling noise at this many samples per pixel."""
    mask = plain["path.length"] > 0
    first = _stack(ghosts, mask) - _stack(plain, mask)
    second = _stack(ghosts_other, mask) - _stack(plain_other, mask)
    return round(float(np.percentile(np.abs(first - second), 99)), 5)


def compare(before, after, prefix, plain):
    """The change from ``before`` to ``after`` on the specimen's pixels, over all 16 channels, against the
    camera's noise at the transmitted image's level."""
    mask = plain["path.length"] > 0
    change = _stack(after, mask) - _stack(before, mask)
    photon = np.sqrt(np.maximum(_stack(plain, mask), 0.0) / FULL_WELL)
    magnitude = np.abs(change)
    row = {"mean_change": round(float(change.mean()), 5),
           "mean_abs": round(float(magnitude.mean()), 5),
           "p99_abs": round(float(np.percentile(magnitude, 99)), 5),
           "max_abs": round(float(magnitude.max()), 5),
           "over_8bit_level": round(float((magnitude > LEVEL).mean()), 4),
           "over_photon_noise": round(float((magnitude > np.maximum(photon, LEVEL / 2)).mean()), 4)}
    row = {prefix + key: value for key, value in row.items()}
    if not prefix:
        row = {"pixels": int(mask.sum()), **row}
    return row


def plot(worst, path):
    row, plain, ghosts = worst
    plt = common.pyplot()
    key = max(MEASUREMENTS, key=lambda k: float(np.abs(ghosts[k] - plain[k]).max()))
    figure, axes = plt.subplots(1, 3, figsize=(12, 4))
    for axis, image, title in ((axes[0], plain[key], "transmitted path"),
                               (axes[1], ghosts[key], f"with ghosts (max_bounces {row['max_bounces']})"),
                               (axes[2], ghosts[key] - plain[key], "difference")):
        shown = axis.imshow(image, cmap="gray" if title != "difference" else "RdBu_r")
        axis.set_title(title, fontsize=9)
        axis.axis("off")
        figure.colorbar(shown, ax=axis, fraction=0.046)
    figure.suptitle(f"{row['scene']} in {row['surrounding']}, {row['view']} view, channel {key}", fontsize=10)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
