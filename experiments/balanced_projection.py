"""Would a field balanced by construction exclude a wrong branch? A result's distance from the nearest balanced one.

For each finished grid reconstruction of a simulated dataset (``mi-nest reconstruct`` output directories, such as
the accuracy suite's), the grid's deviator and that of the grid of the same size fitting the truth best (as
``loss_landscape.py`` fits it) are projected onto the nearest deviator of a stress field with ``div(sigma) = 0``:
least squares over the nodes within one spacing of the part (LSQR), the balanced fields written in Fourier as
``P(k) psi(k) P(k)`` with ``P = I - k k^T / |k|^2`` (central-difference wavenumbers) for any symmetric ``psi``, so
that the mean stress is free, on the grid padded on every side so that the part's surface tractions are free too.
Printed and written per field: the error before and after, and the distance (the least squares' residual relative
to the field's norm near the part). A wrong branch far from every balanced field would be excluded by a field
kind built from stress functions; one close to a balanced field, with the same error once projected, would not.

    python experiments/balanced_projection.py experiments/out/accuracy_suite/accuracy_suite/disk_1kN_256px ...

Writes ``experiments/results/balanced_projection.csv``; prints the CPU and the seconds each projection took.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import common
import numpy as np
import scipy.sparse.linalg
from scipy.spatial import cKDTree

import mi_nest  # noqa: F401  (sets the variant)
from mi_nest.io.grid import grid_nodes
from mi_nest.physics.tensors import stress_matrices
from mi_nest.reconstruct import Reconstruction, metrics
from mi_nest.scene import specimen_shapes

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from reconstruction import cpu_name  # noqa: E402

HERE = Path(__file__).resolve().parents[1]
UPPER = np.triu_indices(3)
# The packed upper triangle weighted so that its Euclidean norm is the tensor's Frobenius norm.
FROBENIUS = np.array([1.0, np.sqrt(2), np.sqrt(2), 1.0, np.sqrt(2), 1.0])


def tensors(nodes: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """``(nz, ny, nx, 3, 3)`` deviators of a grid's stored nodes (``xx, yy, yz, zx, xy``, x fastest)."""
    nx, ny, nz = shape
    xx, yy, yz, zx, xy = np.moveaxis(nodes.reshape(nz, ny, nx, 5), -1, 0)
    return stress_matrices(np.stack([xx, yy, -(xx + yy), yz, zx, xy], -1))


def stored(deviators: np.ndarray) -> np.ndarray:
    """The inverse of :func:`tensors`."""
    d = deviators
    return np.stack([d[..., 0, 0], d[..., 1, 1], d[..., 1, 2], d[..., 2, 0], d[..., 0, 1]], -1).reshape(-1, 5)


def deviatoric(t: np.ndarray) -> np.ndarray:
    return t - np.trace(t, axis1=-2, axis2=-1)[..., None, None] / 3.0 * np.eye(3)


class BalancedProjection:
    """Least squares onto the deviators of divergence-free stresses, over the ``near`` nodes of a grid."""

    def __init__(self, near: np.ndarray, spacing: np.ndarray, padding: int):
        self.near = near                                            # (nz, ny, nx) booleans
        self.inner = tuple(slice(padding, padding + n) for n in near.shape)
        self.padded = tuple(n + 2 * padding for n in near.shape)
        # Wavenumbers of the central second difference, per axis (z, y, x), as components (x, y, z).
        axes = [2.0 * np.sin(np.pi * np.fft.fftfreq(n)) / h for n, h in zip(self.padded, spacing[::-1])]
        kz, ky, kx = np.meshgrid(*axes, indexing="ij")
        k = np.stack([kx, ky, kz], -1)
        length = np.linalg.norm(k, axis=-1, keepdims=True)
        unit = np.divide(k, length, out=np.zeros_like(k), where=length > 0)
        self.projector = np.eye(3) - unit[..., :, None] * unit[..., None, :]
        inside, outside = near.size * 6, int(np.prod(self.padded)) * 6
        self.operator = scipy.sparse.linalg.LinearOperator((inside, outside), matvec=self._apply,
                                                           rmatvec=self._adjoint)

    def _balanced(self, potential: np.ndarray) -> np.ndarray:
        spectrum = np.fft.fftn(potential, axes=(0, 1, 2))
        return np.fft.ifftn(self.projector @ spectrum @ self.projector, axes=(0, 1, 2)).real

    def _unpack(self, packed: np.ndarray, shape: tuple) -> np.ndarray:
        values = packed.reshape(*shape, 6) / FROBENIUS
        t = np.zeros((*shape, 3, 3))
        t[..., UPPER[0], UPPER[1]] = values
        t[..., UPPER[1], UPPER[0]] = values
        return t

    @staticmethod
    def _pack(t: np.ndarray) -> np.ndarray:
        return (t[..., UPPER[0], UPPER[1]] * FROBENIUS).reshape(-1)

    def _apply(self, packed):
        deviators = deviatoric(self._balanced(self._unpack(packed, self.padded)))[self.inner]
        return self._pack(deviators * self.near[..., None, None])

    def _adjoint(self, packed):
        padded = np.zeros((*self.padded, 3, 3))
        padded[self.inner] = deviatoric(self._unpack(packed, self.near.shape) * self.near[..., None, None])
        return self._pack(self._balanced(padded))

    def __call__(self, deviators: np.ndarray, iterations: int) -> tuple[np.ndarray, float]:
        """The nearest balanced deviators (the nodes away from the part kept as they were) and the distance."""
        target = self._pack(deviators * self.near[..., None, None])
        potential = scipy.sparse.linalg.lsqr(self.operator, target, iter_lim=iterations, atol=1e-8, btol=1e-8)[0]
        distance = np.linalg.norm(self.operator.matvec(potential) - target) / np.linalg.norm(target)
        balanced = deviatoric(self._balanced(self._unpack(potential, self.padded)))[self.inner]
        return np.where(self.near[..., None, None], balanced, deviators), float(distance)


def projected(directory: Path, iterations: int, padding: int) -> list[dict]:
    result = Reconstruction.load(directory)
    field = result.field
    if field.kind != "grid":
        raise SystemExit(f"{directory}: a {field.kind} field; only grids are projected")
    _, scene, truth = common.simulated_from(result)
    shapes = specimen_shapes(scene)
    points = metrics.evaluation_points(scene, shapes)
    error_of = metrics.ErrorProbe(truth, points)
    best = metrics.fitted_nodes(field, truth, metrics.evaluation_points(scene, shapes, 3 * metrics.EVALUATION_POINTS))
    nx, ny, nz = field.shape
    spacing = (field.bbox_max - field.bbox_min) / (np.array(field.shape) - 1)
    distance_to_part = cKDTree(points).query(grid_nodes(field.bbox_min, field.bbox_max, field.shape))[0]
    projection = BalancedProjection((distance_to_part < spacing.max()).reshape(nz, ny, nx), spacing, padding)

    def error(nodes):
        field.set_nodes(nodes)
        return error_of(field)

    rows = []
    for name, nodes in (("result", field.nodes()), ("the truth's best grid", best)):
        start = time.perf_counter()
        balanced, distance = projection(tensors(nodes, field.shape), iterations)
        rows.append({"case": directory.name, "field": name, "deviatoric_error": round(error(nodes), 4),
                     "distance_from_balanced": round(distance, 4),
                     "error_once_projected": round(error(stored(balanced)), 4), "iterations": iterations,
                     "padding": padding, "seconds": round(time.perf_counter() - start, 1), "cpu": cpu_name()})
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="+", type=Path, help="reconstruction output directories (grids)")
    parser.add_argument("--iterations", type=int, default=200, help="LSQR iterations per projection")
    parser.add_argument("--padding", type=int, default=4, help="nodes added on every side of the grid")
    parser.add_argument("--output", type=Path, default=HERE / "experiments" / "results" / "balanced_projection")
    args = parser.parse_args()
    print(f"CPU: {cpu_name()}", flush=True)
    rows = []
    for directory in args.results:
        for row in projected(directory, args.iterations, args.padding):
            rows.append(row)
            print(f"{row['case']}, {row['field']}: error {100 * row['deviatoric_error']:.2f}%, "
                  f"{100 * row['distance_from_balanced']:.1f}% from the nearest balanced field, whose error is "
                  f"{100 * row['error_once_projected']:.2f}% ({row['seconds']} s)", flush=True)
        common.write_table(rows, args.output.with_suffix(".csv"))


if __name__ == "__main__":
    main()
