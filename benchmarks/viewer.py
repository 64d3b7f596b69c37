"""Frames per second of ``mi-nest view``: what the viewer renders and encodes per frame, on this machine.

For the disk and the kitten, the frames a user makes by dragging (the pose changes every frame), by moving
the polariscope's angle and the load slider (the pose rests), and in slice mode (the offset moves), each at the
viewer's resolution at rest (256 x 256) and while the view moves (128 x 128), one sample per pixel. A frame is
the render plus its 8-bit PNG (what goes to the browser). The first frame of each kind compiles its kernels
and is not counted; the figure is the median over the rest. The issue's target: 10 frames per second at 256 x
256 on these 2 cores.

    python benchmarks/viewer.py [--frames 20]
"""
from __future__ import annotations

import argparse
import io
import statistics
import time
from dataclasses import replace

import imageio.v3 as iio
import numpy as np

from mi_nest.views.viewer import FrameRenderer, ViewState, to_rgb

from reconstruction import cpu_name

SCENES = ("disk_compression", "kitten")


def frame_seconds(frames: FrameRenderer, states_and_poses, resolution: int) -> list[float]:
    seconds = []
    for state, to_world in states_and_poses:
        start = time.perf_counter()
        frame = frames.render(state, to_world, resolution)
        iio.imwrite(io.BytesIO(), to_rgb(frame.image), extension=".png")
        seconds.append(time.perf_counter() - start)
    return seconds[1:]


def turning(frames: FrameRenderer, count: int):
    """Poses of a drag: the camera turning about the part's centre by 3 degrees a frame."""
    position, look_at, up = frames.reference_camera()
    for index in range(count + 1):
        angle = np.radians(3.0 * index)
        forward = look_at - position
        forward /= np.linalg.norm(forward)
        side = np.cross(forward, up)
        turned = np.cos(angle) * forward + np.sin(angle) * side
        right = np.cross(turned, up)
        right /= np.linalg.norm(right)
        down = np.cross(turned, right)
        rotation = np.stack([right, down, turned], axis=1)
        yield ViewState(wavelength=frames.wavelength), frames.pose_of_camera(_wxyz(rotation), look_at)


def _wxyz(matrix):
    w = np.sqrt(max(1e-12, 1 + np.trace(matrix))) / 2
    return np.array([w, (matrix[2, 1] - matrix[1, 2]) / (4 * w), (matrix[0, 2] - matrix[2, 0]) / (4 * w),
                     (matrix[1, 0] - matrix[0, 1]) / (4 * w)])


def sliders(frames: FrameRenderer, count: int):
    state = ViewState(polariscope="linear", wavelength=frames.wavelength)
    for index in range(count + 1):
        yield replace(state, angle=float(index % 90), load_scale=1.0 + 0.01 * index), frames.reference


def slicing(frames: FrameRenderer, count: int):
    low, high = frames.bounds
    state = ViewState(mode="slice", thickness=float(max(high - low)) / 20, wavelength=frames.wavelength)
    for index in range(count + 1):
        offset = low[2] + (high[2] - low[2]) * (0.2 + 0.6 * index / max(count, 1))
        yield replace(state, offset=float(offset)), frames.reference


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=20, help="frames per kind (default: 20)")
    args = parser.parse_args()
    print(f"CPU: {cpu_name()}")
    print(f"{'scene':18s} {'frames':9s} {'256x256 fps':>12s} {'128x128 fps':>12s}")
    for name in SCENES:
        frames = FrameRenderer(name, {}, 256, 128)
        for label, kind in (("dragging", turning), ("sliders", sliders), ("slice", slicing)):
            rates = []
            for resolution in (256, 128):
                seconds = frame_seconds(frames, kind(frames, args.frames), resolution)
                rates.append(1.0 / statistics.median(seconds))
            print(f"{name:18s} {label:9s} {rates[0]:12.1f} {rates[1]:12.1f}", flush=True)


if __name__ == "__main__":
    main()
