"""Time for drivers and simulated instruments: the wall clock, or a simulated one that sleeps instantly.

Drivers take their clock from the port (``port.clock`` on simulated ports,
the wall clock otherwise), so a simulated motion of several seconds, and every
timeout while waiting for it, costs no real time in tests.
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from serial import SerialBase


class WallClock:
    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class SimulatedClock:
    """A clock that only moves when someone sleeps (or a simulated read times out)."""

    def __init__(self, start: float = 0.0) -> None:
        self._now = float(start)

    def now(self) -> float:
        return self._now

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self._now += float(seconds)


Clock = WallClock | SimulatedClock

WALL_CLOCK = WallClock()


def clock_of(port: SerialBase) -> Clock:
    """The clock a driver on ``port`` waits with."""
    return getattr(port, "clock", None) or WALL_CLOCK
