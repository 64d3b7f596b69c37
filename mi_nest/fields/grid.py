"""Stress sampled on a regular grid, trilinearly interpolated by a 6-channel ``mi.Texture3f``."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..io.grid import StressGrid
from .base import StressField


class GridField(StressField):
    """Trilinear lookup in a nodal grid; outside ``bbox`` the boundary value is repeated.

    The tensor is exposed to ``mi.traverse`` as ``stress`` (differentiable).
    """

    def __init__(self, grid: StressGrid):
        self.bbox_min = mi.ScalarPoint3f(grid.bbox_min)
        self.bbox_max = mi.ScalarPoint3f(grid.bbox_max)
        self.shape = grid.stress.shape[:3]
        self.texture = mi.Texture3f(mi.TensorXf(np.ascontiguousarray(grid.stress, dtype=np.float32)),
                                    filter_mode=dr.FilterMode.Linear,
                                    wrap_mode=dr.WrapMode.Clamp)
        # Nodal samples: map bbox_min/max onto the first/last texel centres.
        nodes = mi.ScalarVector3f(self.shape[2], self.shape[1], self.shape[0])
        self._scale = (nodes - 1) / (nodes * (self.bbox_max - self.bbox_min))
        self._offset = 0.5 / nodes - self.bbox_min * self._scale

    @property
    def node_counts(self) -> tuple[int, int, int]:
        """``(nx, ny, nz)``: the nodes along each axis."""
        return self.shape[2], self.shape[1], self.shape[0]

    def eval(self, p: mi.Point3f) -> tuple[mi.Float, ...]:
        uvw = dr.fma(mi.Point3f(p), self._scale, self._offset)
        return tuple(self.texture.eval(uvw))

    def projected(self, alpha: tuple, beta: tuple) -> ProjectedGrid | None:
        """The grid projected onto one transverse frame (:class:`ProjectedGrid`); None while its tensor is being
        differentiated, whose gradients reach it through the texture's lookup only."""
        if dr.grad_enabled(self.texture.tensor()):
            return None
        return ProjectedGrid(self, alpha, beta)

    def traverse(self, callback: mi.TraversalCallback) -> None:
        callback.put("stress", self.texture.tensor(), mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys: list[str]) -> None:
        self.texture.update_inplace()

    def to_grid(self) -> StressGrid:
        return StressGrid(self.texture.tensor().numpy(), np.array(self.bbox_min), np.array(self.bbox_max))


class ProjectedGrid:
    """A :class:`GridField` as one view with a fixed transverse frame sees it (an orthographic camera: every ray
    shares its direction): two channels per node, ``alpha . s`` and ``beta . s`` (the view's projection
    coefficients, :func:`mi_nest.physics.projection.projection_coefficients`), instead of six.

    Trilinear interpolation and the projection are both linear, so projecting the nodes first gives the same
    values as projecting each interpolated tensor, for a third of the lookups and none of the per-step
    projections. Each node stores, per channel, the bilinear form of its cell's face in its own z plane (from
    itself and its +x, +y and +xy neighbours: ``v00 + fx dx + fy (dy + fx dxy)``): a lookup gathers two packets
    of 8 floats, where the texture gathers eight of 8 (docs/performance.md, "The grid field's lookups"), and
    interpolates with 3 fused multiply-adds per face and channel. Built with Dr.Jit from the texture's
    tensor, once per render, at 8 floats per node.
    """

    def __init__(self, field: GridField, alpha: tuple, beta: tuple):
        nz, ny, nx = field.shape
        self.nodes = (nx, ny, nz)
        self._scale = mi.ScalarVector3f(nx - 1, ny - 1, nz - 1) / (field.bbox_max - field.bbox_min)
        self._offset = -field.bbox_min * self._scale
        node = dr.arange(mi.UInt32, nz * ny * nx)
        stress = [dr.gather(mi.Float, field.texture.tensor().array, node * 6 + c) for c in range(6)]
        projected = [sum(mi.Float(a) * s for a, s in zip(coefficients, stress)) for coefficients in (alpha, beta)]
        dr.eval(projected)
        x, y = node % nx, node // nx % ny
        # The last node of a row or column repeats itself: its cell is never looked up.
        right, up = dr.select(x + 1 < nx, 1, 0), dr.select(y + 1 < ny, nx, 0)
        faces = []
        for channel in projected:
            v00, v10, v01, v11 = (dr.gather(mi.Float, channel, node + n) for n in (0, right, up, right + up))
            faces += [v00, v10 - v00, v01 - v00, (v11 - v10) - (v01 - v00)]
        self.values = dr.empty(mi.Float, nz * ny * nx * len(faces))
        dr.scatter(self.values, mi.ArrayXf(faces), node)

    def eval(self, p: mi.Point3f) -> tuple[mi.Float, mi.Float]:
        """``(alpha . s, beta . s)`` at ``p``; outside the grid its boundary values (the texture's clamp)."""
        return self._lookup(dr.fma(mi.Point3f(p), self._scale, self._offset))

    def eval_ray(self, origin: mi.Point3f, direction: mi.Vector3f, along: mi.Float) -> tuple[mi.Float, mi.Float]:
        """:meth:`eval` at ``origin + along * direction``. Inside a march the ray's origin and direction in grid
        units do not change, so LLVM computes them once per ray instead of once per step."""
        return self._lookup(dr.fma(direction * self._scale, along, dr.fma(origin, self._scale, self._offset)))

    def _lookup(self, position: mi.Point3f) -> tuple[mi.Float, mi.Float]:
        nx, ny, nz = self.nodes
        cells, fractions = [], []
        for coordinate, count in zip(position, self.nodes):
            # Selects rather than dr.clip: x86 has no single instruction for the NaN-propagating minimum and
            # maximum that dr.clip asks LLVM for. Clamped to >= 0, a conversion to Int32 is the floor.
            t = dr.select(coordinate > 0.0, coordinate, 0.0)
            t = dr.select(t < count - 1.0, t, count - 1.0)
            cell = dr.minimum(mi.Int32(t), count - 2)
            cells.append(cell)
            fractions.append(t - mi.Float(cell))
        fx, fy, fz = fractions
        base = mi.UInt32((cells[2] * ny + cells[1]) * nx + cells[0])
        faces = []
        for offset in (0, nx * ny):
            v = dr.gather(mi.ArrayXf, self.values, base + offset, shape=(8, dr.width(base)))
            faces.append([dr.fma(fy, dr.fma(fx, v[c + 3], v[c + 2]), dr.fma(fx, v[c + 1], v[c])) for c in (0, 4)])
        near, far = faces
        return tuple(dr.fma(fz, b - a, a) for a, b in zip(near, far))
