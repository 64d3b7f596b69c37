"""The methods by name (the integrator's ``method`` property, ``--method``), and what each can do."""
from __future__ import annotations

from .auto import Auto
from .guards import SceneSetupError
from .methods import POINTS, RK4, Linear, Magnus4, Method, Product

METHODS: dict[str, type[Method] | type[Auto]] = {cls.name: cls for cls in (Product, Magnus4, Linear, RK4, Auto)}
# The methods that march as they are named (auto chooses one of them per render).
FIXED = tuple(name for name, cls in METHODS.items() if cls is not Auto)
# Those a ray batch can be traced and differentiated with: unitary (or summed) steps.
DIFFERENTIABLE = tuple(name for name in FIXED if METHODS[name].unitary)


def method_named(method: str, points: str = "midpoint", jitter: bool = False,
                 tolerance: float = 1e-3) -> Method | Auto:
    """The method the integrator's ``method``, ``points``, ``jitter`` and ``tolerance`` properties name."""
    if method not in METHODS:
        raise ValueError(f"photoelastic: unknown method '{method}'; choose one of {', '.join(METHODS)}")
    if points not in POINTS:
        raise ValueError(f"photoelastic: unknown points '{points}'; choose one of {', '.join(POINTS)}")
    return METHODS[method].from_options(POINTS[points], jitter, tolerance)


def require_adjoint(method: Method) -> None:
    """Refuse to replay a march backwards that cannot be: a method whose steps are not unitary."""
    if not method.unitary:
        raise ValueError(f"photoelastic: {method.name} is not unitary, so its march cannot be replayed backwards; "
                         f"differentiate with {_quoted(DIFFERENTIABLE)}")


def require_replay_through_refraction(method: Method) -> None:
    """Through refracting surfaces each segment's product is differentiated inside the path's matrix: the
    products have that adjoint, the linear model's summed generator does not."""
    if not method.replays_bent_paths:
        replayed = tuple(name for name, cls in METHODS.items() if getattr(cls, "replays_bent_paths", False))
        raise SceneSetupError(f"photoelastic: gradients through refracting surfaces need {_quoted(replayed)}, "
                              f"not '{method.name}'")


def _quoted(names: tuple) -> str:
    quoted = [f"'{name}'" for name in names]
    return quoted[0] if len(quoted) == 1 else f"{', '.join(quoted[:-1])} or {quoted[-1]}"
