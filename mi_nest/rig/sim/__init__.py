"""Simulated instruments behind pyserial URLs (``ell14sim://NAME``, ``aptsim://NAME``).

``import mi_nest.rig`` registers this package with pyserial, so
``serial.serial_for_url("ell14sim://qwp2")`` opens a simulated ELL14 named
``qwp2``. Devices live in a registry keyed by (scheme, name) and outlive their
ports: a driver that reopens after a disconnect finds the same device, at the
same position. Tests reach a device with :func:`device` to inject faults or
read its true state. Every simulated device runs on one shared
:class:`~mi_nest.rig.clock.SimulatedClock` (:data:`CLOCK`), so the stages and
the waveplate of one rig move in the same simulated time.
"""
from __future__ import annotations

from collections import deque
from typing import Iterator
from urllib.parse import parse_qs, urlsplit

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, to_bytes

from ..clock import SimulatedClock

CLOCK = SimulatedClock()
_DEVICES = {}


def device(url: str) -> SimulatedDevice:
    """The simulated device behind ``url`` (``scheme://name``), created on first use by its port."""
    parts = urlsplit(url)
    key = (parts.scheme, parts.netloc)
    if key not in _DEVICES:
        raise KeyError(f"no simulated device {url!r} has been opened; open it with serial.serial_for_url first")
    return _DEVICES[key]


def reset() -> None:
    """Forget every simulated device and restart the clock (tests call this between cases)."""
    _DEVICES.clear()
    CLOCK.__init__()


class SimulatedDevice:
    """Device state shared by all ports opened on it: byte stream in, byte stream out, injectable faults.

    Subclasses implement :meth:`handle` (one framed message in, reply bytes
    out) and :meth:`frames` (cut complete messages off the input buffer), and
    may produce bytes later from :meth:`poll` (messages sent when a motion ends).
    """

    def __init__(self, name: str, options: dict[str, str]) -> None:
        self.name = name
        self.options = options
        self.clock = CLOCK
        self.input = bytearray()
        self.output = bytearray()
        self.faults = deque()
        self.disconnected = False
        self.log = []            # (time, received message) for tests

    def inject(self, fault: str, count: int = 1, **details: object) -> None:
        """Queue ``count`` occurrences of ``fault`` for the next messages (names are device specific)."""
        for _ in range(count):
            self.faults.append((fault, details))

    def take_fault(self, *names: str) -> tuple[str, dict[str, object]] | None:
        """The next queued fault if it is one of ``names`` (consumed), else None."""
        if self.faults and self.faults[0][0] in names:
            return self.faults.popleft()
        return None

    def receive(self, data: bytes) -> None:
        self.input += data
        for message in self.frames():
            self.log.append((self.clock.now(), bytes(message)))
            self.output += self.handle(message)

    def frames(self) -> Iterator[bytes]:
        raise NotImplementedError

    def handle(self, message: bytes) -> bytes:
        raise NotImplementedError

    def poll(self) -> None:
        """Let simulated time act (motions finish, delayed replies appear)."""


class SimulatedPort(SerialBase):
    """A pyserial port wired to a :class:`SimulatedDevice` instead of a UART.

    Reads that find no byte wait out their timeout on the simulated clock; a
    device marked ``disconnected`` fails every read and write like a pulled
    USB cable. URL options: ``?no_rts=1`` makes setting RTS fail, as on
    adapters without the line.
    """

    scheme = None
    device_class = None

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        parts = urlsplit(self.port)
        if parts.scheme != self.scheme or not parts.netloc:
            raise SerialException(f"expected {self.scheme}://NAME[?option=value...], got {self.port!r}")
        options = {k: v[-1] for k, v in parse_qs(parts.query).items()}
        self._no_rts = options.pop("no_rts", "0") not in ("0", "")
        key = (self.scheme, parts.netloc)
        if key not in _DEVICES:
            _DEVICES[key] = self.device_class(parts.netloc, options)
        self.device = _DEVICES[key]
        if self.device.disconnected:
            raise SerialException(f"{self.port}: device not present (disconnected)")
        self.is_open = True
        if not self._rtscts:
            self._update_rts_state()

    @property
    def clock(self) -> SimulatedClock:
        return CLOCK

    def close(self) -> None:
        self.is_open = False

    def _reconfigure_port(self):
        pass

    def _update_rts_state(self):
        if self.is_open and getattr(self, "_no_rts", False):
            raise SerialException(f"{self.port}: this adapter cannot set RTS")

    def _update_dtr_state(self):
        pass

    def _check(self):
        if not self.is_open:
            raise PortNotOpenError()
        if self.device.disconnected:
            raise SerialException(f"{self.port}: device disconnected")

    @property
    def in_waiting(self) -> int:
        self._check()
        self.device.poll()
        return len(self.device.output)

    def write(self, data: bytes) -> int:
        self._check()
        data = to_bytes(data)
        self.device.receive(data)
        return len(data)

    def read(self, size: int = 1) -> bytes:
        self._check()
        self.device.poll()
        if len(self.device.output) < size and self._timeout:
            CLOCK.sleep(self._timeout)
            self.device.poll()
        self._check()
        data = bytes(self.device.output[:size])
        del self.device.output[:size]
        return data

    def reset_input_buffer(self) -> None:
        self._check()
        self.device.output.clear()

    def reset_output_buffer(self) -> None:
        self._check()
