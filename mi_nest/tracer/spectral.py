"""A spectral march: one ray's Jones product at several wavelengths, sharing the geometry and the stress lookups.

A wavelength changes a step's generator by a factor only, its phase scale
``C(lambda) / lambda`` relative to the medium's own (``render.phase_scale``):
the chord, the steps and the stress sampled at each step are the same for
every wavelength. A spectral march looks the field up once per step and point
(:class:`SharedLookups`) and advances one Jones product per wavelength, its
*lanes*, from that lookup. Where the lookup is what a step costs (a grid's
trilinear gathers, a projected field's), several wavelengths cost much less
than one march each (``benchmarks/spectral.py``).

The products (``product``, ``magnus4``) march their lanes with the algebra of
:class:`SpectralChain`, every other line of their march and replay unchanged;
``linear`` sums one generator and exponentiates it once per lane. ``rk4`` is
not spectral: it is a reference for the speed chart, marched one wavelength
at a time.

A lane's state is four floats; a spectral state is the lanes' side by side,
one flat tuple, so that whatever carries a method's state (loops, replays,
ray batches) carries it unchanged. The fringe a spectral march sums is its
first lane's: the render's ``fringe.order`` and aliasing guard read that
wavelength (the shortest, in the order lights list them: the densest fringes).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import drjit as dr
import mitsuba as mi

from mi_nest.physics import su2

from .auto import Auto
from .methods import ChainMethod, Fringe, Linear, Method, StepSample
from .registry import METHODS

if TYPE_CHECKING:
    from .segment import Segment
    from .setup import SceneSetup

LANE = 4    # floats per lane: one quaternion


class SharedLookups:
    """A step as every lane sees it: the field looked up once per point of the step, whichever lane asks."""

    def __init__(self, sample: StepSample):
        self.sample, self.length = sample, sample.length
        self._generators = {}
        self._jitter = None

    def generator(self, fraction: float | mi.Float, scale: mi.Float = 1.0) -> su2.Generator:
        # A jittered fraction is one Dr.Jit variable (jittered() returns it again): known by its identity.
        key = fraction if isinstance(fraction, float) else id(fraction)
        if key not in self._generators:
            self._generators[key] = self.sample.generator(fraction)
        return su2.Generator(tuple(x * scale for x in self._generators[key]))

    def jittered(self) -> mi.Float:
        if self._jitter is None:
            self._jitter = self.sample.jittered()
        return self._jitter


class ScaledStep:
    """One lane's view of a step: the shared lookups times the lane's phase factor."""

    def __init__(self, shared: SharedLookups, factor: mi.Float):
        self.shared, self.factor, self.length = shared, factor, shared.length

    def generator(self, fraction: float | mi.Float, scale: mi.Float = 1.0) -> su2.Generator:
        return self.shared.generator(fraction, self.factor * scale)

    def jittered(self) -> mi.Float:
        return self.shared.jittered()


class Spectral:
    """What every spectral march shares: the lanes' phase factors, opaque so that another set of wavelengths
    of the same count launches the same kernel."""

    def __init__(self, inner: Method, factors: tuple[float, ...]):
        self.inner, self.factors = inner, tuple(float(f) for f in factors)
        self.name, self.label, self.unitary = inner.name, inner.label, inner.unitary
        self.replays_bent_paths = inner.replays_bent_paths      # the chains' products, lane by lane
        self._opaque = None

    @property
    def lanes(self) -> int:
        return len(self.factors)

    def lane_factors(self) -> list[mi.Float]:
        if self._opaque is None:
            self._opaque = [dr.opaque(mi.Float, f) for f in self.factors]
        return self._opaque

    def jones_lanes(self, state: tuple) -> list[su2.Quaternion]:
        """Each wavelength's Jones quaternion from a ray's state."""
        return split_lanes(self.finish(state))


class SpectralChain(Spectral, ChainMethod):
    """``product`` or ``magnus4`` at several wavelengths: ``ChainMethod``'s march and replay in the algebra of
    lanes, each step one lookup and one propagator per lane."""

    def step(self, sample: StepSample) -> tuple[tuple, Fringe]:
        shared = SharedLookups(sample)
        lanes = [self.inner.step(ScaledStep(shared, factor)) for factor in self.lane_factors()]
        return tuple(x for propagator, _ in lanes for x in propagator), lanes[0][1]

    def identity(self) -> tuple:
        return tuple(su2.identity(mi.Float(0))) * self.lanes

    def multiply(self, a: tuple, b: tuple) -> tuple:
        return _lanewise(su2.multiply, a, b)

    def multiply_renormalized(self, a: tuple, b: tuple) -> tuple:
        return _lanewise(su2.multiply_renormalized, a, b)

    def renormalize(self, a: tuple) -> tuple:
        return _lanewise(su2.renormalize, a)

    def conjugate(self, a: tuple) -> tuple:
        return _lanewise(su2.conjugate, a)


class SpectralLinear(Spectral, Linear):
    """``linear`` at several wavelengths: the one summed generator, exponentiated once per lane (its state is
    the sum, four floats, whatever the number of wavelengths)."""

    def __init__(self, inner: Linear, factors: tuple[float, ...]):
        Spectral.__init__(self, inner, factors)
        self.point, self.jitter = inner.point, inner.jitter

    def march(self, segment: Segment, setup: SceneSetup) -> tuple[su2.Generator, Fringe]:
        total, fringe = Linear.march(self, segment, setup)
        first = self.lane_factors()[0]
        return total, tuple(first * x for x in fringe)

    def finish(self, state: su2.Generator) -> tuple:
        return tuple(x for factor in self.lane_factors()
                     for x in su2.exponential(su2.Generator(tuple(factor * g for g in state))))


# The spectral march of each kind of method; a method without one (rk4) marches one wavelength at a time.
SPECTRAL_MARCHES = {ChainMethod: SpectralChain, Linear: SpectralLinear}


def spectral(method: Method, factors: tuple[float, ...]) -> Spectral:
    """``method`` marching one lane per phase factor (one per wavelength)."""
    if isinstance(method, Spectral):
        method = method.inner
    for kind, march in SPECTRAL_MARCHES.items():
        if isinstance(method, kind):
            return march(method, factors)
    marching = [name for name, cls in METHODS.items() if issubclass(cls, tuple(SPECTRAL_MARCHES)) or cls is Auto]
    raise ValueError(f"photoelastic: '{method.name}' marches one wavelength at a time; for several wavelengths in "
                     f"one march use {', '.join(repr(name) for name in marching)}")


def can_march_spectra(method: Method) -> bool:
    return isinstance(method, tuple(SPECTRAL_MARCHES))


def lane_count(method: Method) -> int:
    """How many Jones products ``method``'s state holds (one per wavelength)."""
    return method.lanes if isinstance(method, Spectral) else 1


def split_lanes(flat: tuple) -> list[su2.Quaternion]:
    """The lanes of a flat spectral state (or of its finished Jones quaternions), one quaternion each."""
    return [su2.Quaternion(tuple(flat[k:k + LANE])) for k in range(0, len(flat), LANE)]


def _lanewise(operation, *states: tuple) -> tuple:
    """``operation`` on each lane of flat spectral states, the lanes side by side again."""
    return tuple(x for lanes in zip(*(split_lanes(s) for s in states)) for x in operation(*lanes))
