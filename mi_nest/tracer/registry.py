"""The one map from a method's name (the integrator's ``method`` property, ``--method``) to its object."""
from __future__ import annotations

from .auto import Auto
from .methods import POINTS, RK4, Linear, Magnus4, Method, Product

# Each method by name, made from the ``point`` fraction, ``jitter`` and ``tolerance``.
METHODS = {Product.name: lambda point, jitter, tolerance: Product(point, jitter),
           Linear.name: lambda point, jitter, tolerance: Linear(point, jitter),
           Magnus4.name: lambda point, jitter, tolerance: Magnus4(),
           RK4.name: lambda point, jitter, tolerance: RK4(),
           Auto.name: lambda point, jitter, tolerance: Auto(tolerance, jitter)}


def method_named(method: str, points: str = "midpoint", jitter: bool = False,
                 tolerance: float = 1e-3) -> Method | Auto:
    """The method the integrator's ``method``, ``points``, ``jitter`` and ``tolerance`` properties name."""
    if method not in METHODS:
        raise ValueError(f"photoelastic: unknown method '{method}'; choose one of {tuple(METHODS)}")
    if points not in POINTS:
        raise ValueError(f"photoelastic: unknown points '{points}'; choose one of {tuple(POINTS)}")
    return METHODS[method](POINTS[points], jitter, tolerance)
