"""Array-library dispatch so the physics runs unchanged on NumPy and Dr.Jit.

The physics functions only need a handful of element-wise operations. They ask
:func:`ops` for the namespace matching their inputs: Dr.Jit arrays (any
variant) select Dr.Jit, everything else (NumPy arrays, Python floats) NumPy.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Sequence, Union

import numpy as np

if TYPE_CHECKING:
    import drjit

# What the physics functions compute on: a Python float, a NumPy array or a Dr.Jit float array.
Array = Union[float, np.ndarray, "drjit.ArrayBase"]


class _NumPyOps:
    sqrt = staticmethod(np.sqrt)
    sin = staticmethod(np.sin)
    cos = staticmethod(np.cos)
    atan2 = staticmethod(np.arctan2)
    abs = staticmethod(np.abs)
    maximum = staticmethod(np.maximum)
    select = staticmethod(np.where)

    @staticmethod
    def fma(a: Array, b: Array, c: Array) -> Array:
        return a * b + c

    @staticmethod
    def sincos(x: Array) -> tuple[Array, Array]:
        return np.sin(x), np.cos(x)

    @staticmethod
    def rsqrt(x: Array) -> Array:
        return 1.0 / np.sqrt(x)

    @staticmethod
    def replace_where(cond: np.ndarray, compute: Callable[..., Sequence[Array]], current: Sequence[Array],
                      args: Sequence[Array]) -> tuple[Array, ...]:
        """``compute(*args)`` where ``cond`` holds, ``current`` elsewhere."""
        if not np.any(cond):
            return current
        return tuple(np.where(cond, new, old) for new, old in zip(compute(*args), current))

    @staticmethod
    def sign(x: Array) -> Array:
        return np.where(x < 0, -1.0, 1.0)


class _DrJitOps:
    def __init__(self) -> None:
        import drjit as dr
        self.sqrt = dr.sqrt
        self.sin = dr.sin
        self.cos = dr.cos
        self.atan2 = dr.atan2
        self.abs = dr.abs
        self.maximum = dr.maximum
        self.select = dr.select
        self.sincos = dr.sincos
        self.rsqrt = dr.rsqrt
        self.fma = dr.fma

        def replace_where(cond: drjit.ArrayBase, compute: Callable[..., Sequence[Array]],
                          current: Sequence[Array], args: Sequence[Array]) -> tuple[Array, ...]:
            # A symbolic if: LLVM skips ``compute`` for every packet with no lane in ``cond``. Both
            # branches take everything they read as arguments: derivatives do not flow through
            # values a symbolic branch captures.
            count = len(args)
            return dr.if_stmt(args=tuple(args) + tuple(current), cond=cond,
                              true_fn=lambda *state: compute(*state[:count]),
                              false_fn=lambda *state: state[count:])
        self.replace_where = replace_where
        self.sign = dr.sign


_numpy_ops = _NumPyOps()
_drjit_ops = None


def ops(*values: Array) -> _NumPyOps | _DrJitOps:
    """Return the operation namespace for ``values`` (Dr.Jit if any is a Dr.Jit array)."""
    global _drjit_ops
    for value in values:
        if type(value).__module__.startswith("drjit"):
            if _drjit_ops is None:
                _drjit_ops = _DrJitOps()
            return _drjit_ops
    return _numpy_ops
