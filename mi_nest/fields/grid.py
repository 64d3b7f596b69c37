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

    def traverse(self, callback: mi.TraversalCallback) -> None:
        callback.put("stress", self.texture.tensor(), mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys: list[str]) -> None:
        self.texture.update_inplace()

    def to_grid(self) -> StressGrid:
        return StressGrid(self.texture.tensor().numpy(), np.array(self.bbox_min), np.array(self.bbox_max))
