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
    projections. Each node is stored beside its +x neighbour: a lookup gathers four packets of 4 floats, where
    the texture gathers eight of 8 (docs/performance.md, "The grid field's lookups"). Built with Dr.Jit from
    the texture's tensor, once per render.
    """

    def __init__(self, field: GridField, alpha: tuple, beta: tuple):
        nz, ny, nx = field.shape
        self.nodes = (nx, ny, nz)
        self._scale = mi.ScalarVector3f(nx - 1, ny - 1, nz - 1) / (field.bbox_max - field.bbox_min)
        self._offset = -field.bbox_min * self._scale
        slot = dr.arange(mi.UInt32, nz * ny * nx * 4)
        node = slot // 4
        # Slots 2 and 3 hold the +x neighbour's channels (the last node repeats itself: its cell is never used).
        source = dr.select(((slot & 2) != 0) & (node % nx + 1 < nx), node + 1, node)
        stress = [dr.gather(mi.Float, field.texture.tensor().array, source * 6 + c) for c in range(6)]
        projected = [sum(mi.Float(a) * s for a, s in zip(coefficients, stress)) for coefficients in (alpha, beta)]
        self.values = dr.select((slot & 1) == 0, *projected)

    def eval(self, p: mi.Point3f) -> tuple[mi.Float, mi.Float]:
        """``(alpha . s, beta . s)`` at ``p``; outside the grid its boundary values (the texture's clamp)."""
        nx, ny, nz = self.nodes
        position = dr.fma(mi.Point3f(p), self._scale, self._offset)
        cells, fractions = [], []
        for coordinate, count in zip(position, self.nodes):
            t = dr.clip(coordinate, 0.0, count - 1.0)
            cell = dr.minimum(mi.UInt32(t), count - 2)
            cells.append(cell)
            fractions.append(t - mi.Float(cell))
        fx, fy, fz = fractions
        base = (cells[2] * ny + cells[1]) * nx + cells[0]
        rows = [dr.gather(mi.Vector4f, self.values, base + offset) for offset in (0, nx, nx * ny, nx * ny + nx)]
        along_x = [dr.fma(fx, mi.Vector2f(r.z, r.w) - mi.Vector2f(r.x, r.y), mi.Vector2f(r.x, r.y)) for r in rows]
        near = dr.fma(fy, along_x[1] - along_x[0], along_x[0])
        far = dr.fma(fy, along_x[3] - along_x[2], along_x[2])
        value = dr.fma(fz, far - near, near)
        return value.x, value.y
