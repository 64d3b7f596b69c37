"""Models of the ordered exponential along a ray (docs/physics.md section 4), one object each.

A method defines its step once: what one step contributes, from the step
generator sampled where the method wants it within the step. The same
definition marches the segments of the integrator's walk (Dr.Jit, in a
symbolic loop) and, for the methods that are products of unitary steps, chords
of NumPy arrays (:meth:`ChainMethod.march_chords`), which is what ``auto``'s
step doubling measures. A method also says how segments combine along a ray
and how the adjoint pass replays them. ``registry.py`` maps the names of the
integrator's ``method`` property to these classes; nothing else reads the name.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, NamedTuple, Protocol

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_nest.physics import su2
from mi_nest.physics.backend import Array

from .segment import Segment

if TYPE_CHECKING:
    from .setup import SceneSetup

# Where a one-point rule samples each step, as a fraction of it: its midpoint (second order) or its start (first).
POINTS = {"midpoint": 0.5, "left": 0.0}
# Gauss-Legendre points of Magnus-4 within a step (fractions of it from the camera side):
# the farther one from the camera first, as the light meets it.
GAUSS_POINTS = (0.5 + 3.0 ** 0.5 / 6.0, 0.5 - 3.0 ** 0.5 / 6.0)

# ``(b, c)`` of a step's generator times its length: what the fringe-order channel sums.
Fringe = tuple


# NumPy ``points (..., 3) -> (p, q)``: the step generator per mm at points (mm).
GeneratorField = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


class StepSample(Protocol):
    """One step as a method sees it (or, on NumPy, every step of several chords at once)."""

    length: Array       # mm; zero for the padding past a chord's last step, which then changes nothing

    def generator(self, fraction: float | Array, scale: Array = 1.0) -> su2.Generator:
        """The step generator per mm at ``fraction`` of the step (0 on the camera side), times ``scale``."""

    def jittered(self) -> Array:
        """A uniformly random fraction of the step, the same in every pass over it (Dr.Jit only)."""


class Decision(NamedTuple):
    """The method and step size a render marches with, and for ``auto`` why."""
    method: Method
    step_size: float
    reason: str | None = None


class Method:
    """A model of the ordered exponential: segments combine by products (``linear``: by a sum)."""

    name = ""               # the integrator's ``method`` property
    label = ""              # what it is, for people
    # Whether every step is unitary: the adjoint replay peels steps off with conjugates.
    unitary = True
    # Whether each segment's product can be differentiated inside a refracted path's matrix.
    replays_bent_paths = False
    # Whether the ``points`` property chooses where it samples each step.
    takes_points = False

    @classmethod
    def from_options(cls, point: float, jitter: bool, tolerance: float) -> Method:
        """The method from the integrator's ``points`` (as a fraction of the step), ``jitter`` and ``tolerance``,
        those it uses."""
        return cls()

    def decide(self, setup: SceneSetup, scene: mi.Scene, sensor: mi.Sensor | None,
               step_size: float) -> Decision:
        return Decision(self, step_size)

    def start(self) -> su2.Quaternion:
        """A ray's state before its first segment."""
        return su2.identity(mi.Float(0))

    def accumulate(self, state: su2.Quaternion, segment: su2.Quaternion) -> su2.Quaternion:
        """A ray's state after one more segment."""
        return su2.multiply(state, segment)

    def finish(self, state: su2.Quaternion) -> su2.Quaternion:
        """The Jones quaternion from a ray's state."""
        return state

    def march(self, segment: Segment, setup: SceneSetup) -> tuple[su2.Quaternion, Fringe]:
        """A walk's segment: its state (what :meth:`accumulate` takes) and its summed fringe generator."""
        raise NotImplementedError

    def trace(self, progress: tuple, segment: Segment, setup: SceneSetup) -> tuple:
        """The primal pass over one segment; ``progress`` is ``(state, fringe)``, from :meth:`trace_start`."""
        state, fringe = progress
        result, segment_fringe = self.march(segment, setup)
        return self.accumulate(state, result), _add(fringe, segment_fringe)

    def trace_start(self) -> tuple:
        return self.start(), (mi.Float(0), mi.Float(0))

    def replay_start(self, state: su2.Quaternion) -> Any:
        """The adjoint pass's progress (what it threads from segment to segment) for a ray whose traced state
        is ``state``."""
        raise NotImplementedError

    def replay(self, progress: Any, state_grad: su2.Quaternion, segment: Segment, setup: SceneSetup) -> Any:
        """Back-propagate ``state_grad`` (the adjoint of the ray's state) into one segment's field lookups."""
        raise NotImplementedError


class ChainMethod(Method):
    """A product of unitary per-step propagators (``product``, ``magnus4``).

    Its march and replay multiply in the algebra below: one unit quaternion per
    ray; a spectral march's (``spectral.py``) is one per wavelength.
    """

    replays_bent_paths = True

    def step(self, sample: StepSample) -> tuple[su2.Quaternion, Fringe]:
        """The step's propagator and ``(b, c)`` of its mean generator times its length."""
        raise NotImplementedError

    def identity(self) -> su2.Quaternion:
        return su2.identity(mi.Float(0))

    def multiply(self, a: su2.Quaternion, b: su2.Quaternion) -> su2.Quaternion:
        return su2.multiply(a, b)

    def multiply_renormalized(self, a: su2.Quaternion, b: su2.Quaternion) -> su2.Quaternion:
        return su2.multiply_renormalized(a, b)

    def renormalize(self, a: su2.Quaternion) -> su2.Quaternion:
        return su2.renormalize(a)

    def conjugate(self, a: su2.Quaternion) -> su2.Quaternion:
        return su2.conjugate(a)

    def start(self) -> su2.Quaternion:
        return self.identity()

    def accumulate(self, state: su2.Quaternion, segment: su2.Quaternion) -> su2.Quaternion:
        return self.multiply(state, segment)

    @dr.syntax
    def march(self, segment: Segment, setup: SceneSetup) -> tuple[su2.Quaternion, Fringe]:
        """Ordered product of the segment's steps.

        Marching away from the camera goes against the light, so later steps
        multiply on the right. The chord's front and back halves are two
        independent products advanced in the same iteration (then joined, which
        is exact): two dependency chains keep the vector units busy where a
        single chain would leave them waiting on its latency. Each iteration
        takes two steps of each half and multiplies them together first, so a
        half's running product (and its renormalisation) waits on one product
        per two steps: 6 to 8% faster than one step per iteration. Up to three
        indices past the end are zero-length steps, which change nothing.
        """
        half = (segment.steps + 3) // 4 * 2
        front = self.identity()
        back = self.identity()
        fringe = (mi.Float(0), mi.Float(0))
        i = mi.UInt32(0)
        while dr.hint(i < half, exclude=[half, segment, self, setup]):
            front_steps, front_fringe = self._two_steps(segment, setup, i)
            back_steps, back_fringe = self._two_steps(segment, setup, i + half)
            front = self.multiply_renormalized(front, front_steps)
            back = self.multiply_renormalized(back, back_steps)
            fringe = _add(fringe, _add(front_fringe, back_fringe))
            i += 2
        return self.multiply(front, back), fringe

    def _two_steps(self, segment: Segment, setup: SceneSetup, index: mi.UInt32) -> tuple[su2.Quaternion, Fringe]:
        """Steps ``index`` and ``index + 1`` as one propagator, and their fringe."""
        first, first_fringe = self.step(SegmentStep(segment, setup, index))
        second, second_fringe = self.step(SegmentStep(segment, setup, index + 1))
        return self.multiply(first, second), _add(first_fringe, second_fringe)

    def march_chords(self, generator: GeneratorField, starts: np.ndarray, direction: np.ndarray,
                     lengths: np.ndarray, step_size: float) -> su2.Quaternion:
        """Jones quaternions of NumPy chords ``starts + t direction``, ``t`` in ``[0, lengths]``.

        Marched as a walk marches a segment: ``ceil(L / step_size)`` equal steps
        from the camera side, later steps on the right. ``generator(points)``
        gives the generator ``(p, q)`` per mm at ``(..., 3)`` points.
        """
        q, _ = self.step(ChordSteps(generator, starts, direction, lengths, step_size))
        # Ordered product along each chord by pairwise halving (associative; padding is the identity).
        while q[0].shape[1] > 1:
            if q[0].shape[1] % 2:
                q = tuple(np.concatenate([x, np.full((len(x), 1), float(i == 0))], axis=1) for i, x in enumerate(q))
            q = su2.multiply(tuple(x[:, 0::2] for x in q), tuple(x[:, 1::2] for x in q))
        return su2.Quaternion(tuple(x[:, 0] for x in q))

    def replay_start(self, state: su2.Quaternion) -> tuple[su2.Quaternion, su2.Quaternion]:
        return self.identity(), tuple(mi.Float(x) for x in state)

    @dr.syntax
    def replay(self, progress: tuple[su2.Quaternion, su2.Quaternion], state_grad: su2.Quaternion, segment: Segment,
               setup: SceneSetup) -> tuple[su2.Quaternion, su2.Quaternion]:
        """Products ``J = A U B``: a step ``U`` receives ``conj(A) dJ conj(B)``.

        ``A`` (the steps before) grows and ``B = conj(U) B`` (the steps after,
        from the primal ``J``) shrinks as the replay advances: both are exact
        since every step is unitary, so nothing per step is stored.
        """
        before, after = progress
        i = mi.UInt32(0)
        while dr.hint(i < segment.steps, exclude=[segment, self, setup, state_grad]):
            with dr.resume_grad():
                propagator, _ = self.step(SegmentStep(segment, setup, i))
                unit = dr.detach(propagator)
                after = self.renormalize(self.multiply(self.conjugate(unit), after))
                adjoint = self.multiply(self.multiply(self.conjugate(before), state_grad), self.conjugate(after))
                dr.backward_from(_dot(adjoint, propagator))
            before = self.multiply_renormalized(before, unit)
            i += 1
        return before, after


class OnePointRule:
    """Samples the generator at one point of each step: ``point`` (a fraction of it) or, jittered, anywhere."""

    def __init__(self, point: float = POINTS["midpoint"], jitter: bool = False):
        self.point, self.jitter = point, jitter

    @classmethod
    def from_options(cls, point: float, jitter: bool, tolerance: float) -> OnePointRule:
        return cls(point, jitter)

    def step_generator(self, sample: StepSample) -> su2.Generator:
        """The generator at the step's point times the step's length."""
        return sample.generator(sample.jittered() if self.jitter else self.point, sample.length)


class Product(OnePointRule, ChainMethod):
    """The exact exponential of the generator sampled at one point of each step."""

    name = "product"
    label = "NeST-general (a product of exact steps)"
    takes_points = True

    def step(self, sample: StepSample) -> tuple[su2.Quaternion, Fringe]:
        generator = self.step_generator(sample)
        return su2.exponential(generator), generator[1:3]


class Magnus4(ChainMethod):
    """The exponential of the fourth-order Magnus term: two Gauss points and their commutator."""

    name = "magnus4"
    label = "4th-order Magnus steps"

    def step(self, sample: StepSample) -> tuple[su2.Quaternion, Fringe]:
        first, second = (sample.generator(g) for g in GAUSS_POINTS)
        half = 0.5 * sample.length
        return su2.magnus4(first, second, sample.length), (half * (first[1] + second[1]),
                                                             half * (first[2] + second[2]))


class Linear(OnePointRule, Method):
    """The generator summed along the ray (one point per step), exponentiated once: exact when steps commute."""

    name = "linear"
    label = "NeST-approx (the linear model)"

    def step(self, sample: StepSample) -> tuple[su2.Generator, Fringe]:
        """The step's share of the summed generator, and its ``(b, c)``."""
        increment = self.step_generator(sample)
        return increment, increment[1:3]

    def start(self) -> su2.Generator:
        zero = mi.Float(0)
        return su2.Generator((zero, zero, zero, zero))

    def accumulate(self, state: su2.Generator, segment: su2.Generator) -> su2.Generator:
        return su2.Generator(_add(state, segment))

    def finish(self, state: su2.Generator) -> su2.Quaternion:
        return su2.exponential(state)

    @dr.syntax
    def march(self, segment: Segment, setup: SceneSetup) -> tuple[su2.Generator, Fringe]:
        total = (mi.Float(0), mi.Float(0), mi.Float(0), mi.Float(0))
        i = mi.UInt32(0)
        while dr.hint(i < segment.steps, exclude=[segment, self, setup]):
            increment, _ = self.step(SegmentStep(segment, setup, i))
            total = _add(total, increment)
            i += 1
        return total, total[1:3]

    def replay_start(self, state: su2.Generator) -> mi.Float:
        return mi.Float(0)      # the state is a sum: every step receives the ray's adjoint itself

    @dr.syntax
    def replay(self, progress: mi.Float, state_grad: su2.Generator, segment: Segment, setup: SceneSetup) -> mi.Float:
        i = mi.UInt32(0)
        while dr.hint(i < segment.steps, exclude=[segment, self, setup, state_grad]):
            with dr.resume_grad():
                increment, _ = self.step(SegmentStep(segment, setup, i))
                dr.backward_from(_dot(state_grad, increment))
            i += 1
        return progress


class RK4(Method):
    """Classical Runge-Kutta on ``K' = K A(t)`` (t from the camera): fourth order, not unitary.

    Its amplification per step is ``|R(i x)|^2 = 1 - x^6/72 + x^8/576`` for a
    phase ``x`` per step: it damps below ``x = 2 sqrt(2)`` and blows up above.
    """

    name = "rk4"
    label = "classical Runge-Kutta (not unitary)"
    unitary = False

    def advance(self, k: su2.Quaternion, sample: StepSample) -> tuple[su2.Quaternion, Fringe]:
        """``K`` after one more step, and ``(b, c)`` of the step's midpoint generator times its length."""
        h = sample.length
        a0, am, a1 = (sample.generator(f) for f in (0.0, 0.5, 1.0))
        k1 = su2.multiply(k, a0)
        k2 = su2.multiply(_axpy(0.5 * h, k1, k), am)
        k3 = su2.multiply(_axpy(0.5 * h, k2, k), am)
        k4 = su2.multiply(_axpy(h, k3, k), a1)
        slope = tuple(y1 + 2.0 * y2 + 2.0 * y3 + y4 for y1, y2, y3, y4 in zip(k1, k2, k3, k4))
        return _axpy(h / 6.0, slope, k), tuple(h * x for x in am[1:3])

    @dr.syntax
    def march(self, segment: Segment, setup: SceneSetup) -> tuple[su2.Quaternion, Fringe]:
        k = su2.identity(mi.Float(0))
        fringe = (mi.Float(0), mi.Float(0))
        i = mi.UInt32(0)
        while dr.hint(i < segment.steps, exclude=[segment, self, setup]):
            k, step_fringe = self.advance(k, SegmentStep(segment, setup, i))
            fringe = _add(fringe, step_fringe)
            i += 1
        return k, fringe


class SegmentStep:
    """Step ``index`` of a walk's segment, marched by Dr.Jit."""

    def __init__(self, segment: Segment, setup: SceneSetup, index: mi.UInt32):
        self.segment, self.setup, self.index = segment, setup, index
        self.length = dr.select(index < segment.steps, segment.h, 0.0)

    def generator(self, fraction: float | mi.Float, scale: mi.Float = 1.0) -> su2.Generator:
        along = (mi.Float(self.index) + fraction) * self.segment.h
        return su2.generator(*self.setup.transverse(self.segment, along), scale)

    def jittered(self) -> mi.Float:
        # A hash of (segment, index), not a sampler's next number: the adjoint replay visits the
        # steps in another order and must sample the same points.
        return mi.sample_tea_float32(self.segment.seed, self.index)


class ChordSteps:
    """Every step of NumPy chords at once, as ``(chords, steps)`` arrays padded with zero-length steps."""

    def __init__(self, generator: GeneratorField, starts: np.ndarray, direction: np.ndarray,
                 lengths: np.ndarray, step_size: float):
        lengths = np.asarray(lengths, dtype=np.float64)
        counts = np.maximum(np.ceil(lengths / step_size - 1e-9), 1).astype(np.int64)
        self.h = lengths / counts
        self.index = np.arange(counts.max())
        self.length = np.where(self.index[None, :] < counts[:, None], self.h[:, None], 0.0)
        self.field, self.starts, self.direction = generator, starts, direction

    def generator(self, fraction: float, scale: np.ndarray = 1.0) -> su2.Generator:
        along = ((self.index[None, :] + fraction) * self.h[:, None])[..., None]
        return su2.generator(*self.field(self.starts[:, None, :] + along * self.direction), scale)


def _add(x, y):
    return tuple(xi + yi for xi, yi in zip(x, y))


def _axpy(a, x, y):
    return tuple(a * xi + yi for xi, yi in zip(x, y))


def _dot(x, y):
    return sum(a * b for a, b in zip(x, y))
