"""NumPy values handed to Dr.Jit in memory that keeps its kernels reusable."""
from __future__ import annotations

from typing import TypeVar

import numpy as np

Array = TypeVar("Array")


def device_array(kind: type[Array], values: np.ndarray, dtype: type = np.float32) -> Array:
    """A Dr.Jit array of NumPy ``values`` (one row per component) in 64-byte aligned memory.

    Dr.Jit adopts a NumPy buffer as it is, and compiles the kernels that read it
    for its alignment: arrays from ordinary NumPy memory, aligned differently
    from call to call, would make a training loop (or a viewer) rebuild its kernels.
    """
    values = np.asarray(values, dtype=dtype)
    if values.ndim == 1:
        return kind(_aligned(values))
    return kind(*(_aligned(row) for row in values))


def _aligned(row):
    storage = np.empty(row.size + 64 // row.itemsize, dtype=row.dtype)
    start = (-storage.ctypes.data % 64) // row.itemsize
    aligned = storage[start:start + row.size]
    aligned[:] = row
    return aligned
