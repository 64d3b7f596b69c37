"""Camera rays of dataset pixels: the scene's polariscope camera moved to each rotation's pose."""
from __future__ import annotations

import drjit as dr
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
        film = np.stack([(columns + jitter[:, 0]) / width, (rows + jitter[:, 1]) / height])
        ray, _ = self.sensor.sample_ray(0.0, 0.0, device_array(mi.Point2f, film), mi.Point2f(0.5, 0.5))
        # The camera at rotation p is the camera as it stands moved by M_p = to_world_p current^-1, and so
        # are its rays: one sampling pass serves every rotation of the batch. The moves are gathered per
        # ray on the device, so the rays stay unevaluated until the march that reads them.
        views, index = np.unique(positions, return_inverse=True)
        moves, rights = self._moves(views)
        ray_view = device_array(mi.UInt32, index, np.uint32)
        row = [dr.gather(mi.Vector4f, moves, ray_view * 3 + i) for i in range(3)]
        o, d = mi.Point3f(ray.o), mi.Vector3f(ray.d)
        origins = mi.Point3f(*(dr.fma(r.x, o.x, dr.fma(r.y, o.y, dr.fma(r.z, o.z, r.w))) for r in row))
        directions = dr.normalize(mi.Vector3f(*(dr.fma(r.x, d.x, dr.fma(r.y, d.y, r.z * d.z)) for r in row)))
        return mi.Ray3f(origins, directions), dr.gather(mi.Vector3f, rights, ray_view)

    def _moves(self, views: np.ndarray) -> tuple[mi.Float, mi.Float]:
        """The top three rows of each rotation's move ``M_p`` and its image-right direction, flat on the
        device (12 and 3 numbers per rotation of ``views``)."""
        current = np.array(self.sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
        poses = np.stack([self.dataset.to_world(int(p)) for p in views])
        moves = (poses @ np.linalg.inv(current))[:, :3, :]
        rights = -poses[:, :3, 0] / np.linalg.norm(poses[:, :3, 0], axis=1, keepdims=True)
        return device_array(mi.Float, moves.ravel()), device_array(mi.Float, rights.ravel())

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
