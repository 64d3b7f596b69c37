"""Camera rays of dataset pixels: the scene's polariscope camera moved to each rotation's pose."""
from __future__ import annotations

import mitsuba as mi
import numpy as np

from ..arrays import device_array
from ..dataset import Dataset
from ..scene import SceneError, polariscope_camera

class ViewRays:
    """Rays through pixels of any rotation of ``dataset``, from the scene's camera model."""

    def __init__(self, scene: mi.Scene, dataset: Dataset):
        self.dataset = dataset
        self.sensor = polariscope_camera(scene)
        size = tuple(int(x) for x in self.sensor.film().size())
        if size != tuple(dataset.resolution):
            raise SceneError(f"the scene's film is {size[0]}x{size[1]}, the dataset's images "
                             f"{dataset.resolution[0]}x{dataset.resolution[1]}; load the scene with the dataset's "
                             "resolution (e.g. res=...)")

    def rays(self, positions: np.ndarray, rows: np.ndarray, columns: np.ndarray,
             jitter: np.ndarray | None = None) -> tuple[mi.Ray3f, mi.Vector3f]:
        """``(mi.Ray3f, right)`` for pixels ``(rows, columns)`` of rotations ``positions``.

        ``jitter`` (N, 2) in [0, 1) places each ray within its pixel (None: the
        pixel centre); a pixel's measurement averages over its area, so random
        positions fit it without bias. ``right`` is each ray's image-right
        direction, which fixes the polariscope frame.
        """
        positions, rows, columns = (np.asarray(a) for a in (positions, rows, columns))
        if jitter is None:
            jitter = np.full((len(rows), 2), 0.5)
        width, height = self.dataset.resolution
        film = np.stack([(columns + jitter[:, 0]) / width, (rows + jitter[:, 1]) / height], axis=-1)
        # The camera at rotation p is the camera as it stands moved by M_p = to_world_p current^-1, and so
        # are its rays: one sampling pass serves every rotation of the batch.
        ray, _ = self.sensor.sample_ray(0.0, 0.0, mi.Point2f(film.T.astype(np.float32)), mi.Point2f(0.5, 0.5))
        # An orthographic camera returns one direction for all rays.
        origins, directions = (np.broadcast_to(np.array(x, dtype=np.float64).T, (len(rows), 3))
                               for x in (ray.o, ray.d))
        current = np.array(self.sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
        views, index = np.unique(positions, return_inverse=True)
        poses = np.stack([self.dataset.to_world(int(p)) for p in views])
        moves = (poses @ np.linalg.inv(current))[index]
        origins = np.einsum("nij,nj->ni", moves[:, :3, :3], origins) + moves[:, :3, 3]
        directions = np.einsum("nij,nj->ni", moves[:, :3, :3], directions)
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        rights = -poses[index, :3, 0] / np.linalg.norm(poses[index, :3, 0], axis=1, keepdims=True)
        return (mi.Ray3f(device_array(mi.Point3f, origins.T), device_array(mi.Vector3f, directions.T)),
                device_array(mi.Vector3f, rights.T))

    def view(self, position: int) -> tuple[mi.Ray3f, mi.Vector3f]:
        """Rays through every pixel centre of rotation ``position``, row-major."""
        width, height = self.dataset.resolution
        rows, columns = np.divmod(np.arange(width * height), width)
        return self.rays(np.full(rows.shape, position), rows, columns)


def stratified(pixels: int, samples: int, rng: np.random.Generator) -> np.ndarray:
    """``(pixels * samples, 2)`` positions in [0, 1)^2: one per cell of a near-square grid per pixel."""
    columns = int(np.ceil(np.sqrt(samples)))
    rows = int(np.ceil(samples / columns))
    cells = np.arange(samples)
    offsets = np.stack([cells % columns, cells // columns], axis=-1) / np.array([columns, rows])
    jitter = rng.random((pixels, samples, 2)) / np.array([columns, rows])
    return (offsets[None] + jitter).reshape(-1, 2)
