"""Driver for the Thorlabs Elliptec ELL14 rotation mount that turns QWP2, the camera-side quarter-wave plate.

A waveplate left at a wrong angle silently corrupts every intensity of a
tomography run, so this driver trusts no reply it has not checked: every move
ends by reading the position back (``gp``) and comparing it with the target;
a move is sent again at most once, and only after that read-back, never
blindly; every failure is raised with the module's own status code.
Queries (``in``, ``gs``, ``gp``) move nothing, so they are retried freely.

The same code drives ``ell14sim://NAME`` and a real port (``/dev/ttyUSB0``):
all waiting uses the port's clock (:func:`~mi_nest.rig.clock.clock_of`), and
counts per degree come from the mount's own ``in`` reply.
"""
from __future__ import annotations

import math

import serial

from . import elliptec
from .clock import clock_of
from .errors import CommunicationError, DeviceBusy, MotionError, RigError

# Port read timeout and pause between busy polls: longer than a whole reply (35 bytes take 36 ms at 9600 baud).
POLL_INTERVAL = 0.05
_PORT_ERRORS = (serial.SerialException, OSError)


class _NoValidReply(Exception):
    """No reply in time, or a garbled one (the input is already resynchronised): worth another look."""


class ELL14:
    """One ELL14 on a serial bus. Angles are degrees on one turn, ``0 <= angle < 360``.

    ``tolerance_counts`` (default 24, about 0.06 degrees) is what a move may
    miss by: the ELL14's specified repeatability is 0.05 degrees. The angle
    actually reached is what ``move_to`` returns and what datasets record.
    """

    def __init__(self, url: str, address: str = "0", timeout: float = 0.5, retries: int = 2, *,
                 move_timeout: float = 8.0, busy_timeout: float = 10.0, tolerance_counts: int = 24,
                 port_factory=serial.serial_for_url):
        self.url = url
        self.address = elliptec.check_address(address)
        if retries < 0:
            raise ValueError(f"retries must be 0 or more, got {retries}")
        self.timeout = timeout
        self.retries = retries
        self.move_timeout = move_timeout
        self.busy_timeout = busy_timeout
        self.tolerance_counts = tolerance_counts
        self.name = f"ELL14 {self.address} on {url}"
        self._port_factory = port_factory
        self._port = None
        self.reopen()

    def reopen(self) -> None:
        """Open the port and identify the mount (again, after a disconnect)."""
        self.close()
        try:
            self._port = self._port_factory(self.url, baudrate=9600, bytesize=serial.EIGHTBITS,
                                            parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE,
                                            timeout=POLL_INTERVAL, xonxoff=False, rtscts=False)
        except _PORT_ERRORS as exc:
            raise CommunicationError(f"cannot open the port: {exc}", self.name) from exc
        self._clock = clock_of(self._port)
        try:
            info = self._query(elliptec.get_info(self.address), "IN").value
            if info.ell_type != elliptec.ELL14_TYPE:
                raise RigError(f"the module is an ELL{info.ell_type}, not an ELL14", self.name)
            if info.pulses_per_unit <= 0:
                raise RigError(f"the module reports {info.pulses_per_unit} counts per revolution", self.name)
        except RigError:
            self.close()
            raise
        self.info = info

    def close(self) -> None:
        if self._port is not None:
            port, self._port = self._port, None
            port.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def pulses_per_revolution(self) -> int:
        return self.info.pulses_per_unit

    @property
    def counts_per_degree(self) -> float:
        return self.pulses_per_revolution / 360.0

    def degrees_to_counts(self, degrees: float) -> int:
        """The target on one turn: angles that differ by whole turns give the same counts."""
        if not math.isfinite(degrees):
            raise ValueError(f"angle must be a finite number of degrees, got {degrees!r}")
        return round(degrees % 360.0 * self.counts_per_degree) % self.pulses_per_revolution

    def counts_to_degrees(self, counts: int) -> float:
        return counts % self.pulses_per_revolution / self.counts_per_degree

    def position(self) -> float:
        return self.counts_to_degrees(self._query(elliptec.get_position(self.address), "PO").value)

    def home(self, clockwise: bool = True) -> float:
        """Home (to count 0: the driver assumes the factory home offset) and return the measured angle."""
        return self._move(elliptec.home(self.address, clockwise), 0, "home")

    def move_to(self, degrees: float) -> float:
        """Turn to ``degrees`` (any finite angle, taken modulo 360) and return the measured angle."""
        target = self.degrees_to_counts(degrees)
        return self._move(elliptec.move_absolute(self.address, target), target, f"move to {degrees} deg")

    def _move(self, command: bytes, target: int, what: str) -> float:
        for _attempt in range(2):
            self._run_motion(command, what)
            measured = self._query(elliptec.get_position(self.address), "PO").value
            half_turn = self.pulses_per_revolution // 2
            error = (measured - target + half_turn) % self.pulses_per_revolution - half_turn
            if abs(error) <= self.tolerance_counts:
                return self.counts_to_degrees(measured)
        raise MotionError(f"{what}: the mount stopped at {self.counts_to_degrees(measured):.4f} deg, "
                          f"{error} counts from the target, twice", self.name)

    def _run_motion(self, command: bytes, what: str) -> None:
        """Send one motion command and wait until the mount is still; raise on a device error."""
        self._send(command)
        try:
            reply = self._read_reply(self.move_timeout, ("PO", "GS"))
        except _NoValidReply:
            reply = None     # lost or garbled: the status and the read-back tell what happened
        if reply is not None and reply.kind == "PO":
            return
        if reply is None or reply.value in (elliptec.OK, elliptec.BUSY):
            code = self._wait_until_idle()
        else:
            code = reply.value
        if code != elliptec.OK:
            raise self._status_error(code, what)

    def _wait_until_idle(self) -> int:
        """Poll ``gs`` while the module is busy, at most ``busy_timeout``; return its last status code."""
        deadline = self._clock.now() + self.busy_timeout
        while True:
            code = self._query(elliptec.get_status(self.address), "GS").value
            if code != elliptec.BUSY:
                return code
            if self._clock.now() >= deadline:
                raise DeviceBusy(f"still busy after {self.busy_timeout} s", self.name, code)
            self._clock.sleep(POLL_INTERVAL)

    def _query(self, command: bytes, kind: str) -> elliptec.Reply:
        what = command.decode("ascii")
        for _attempt in range(self.retries + 1):
            self._send(command)
            try:
                reply = self._read_reply(self.timeout, (kind, "GS"))
            except _NoValidReply as exc:
                failure = CommunicationError(f"{what!r}: {exc}, {self.retries + 1} attempts", self.name)
                continue
            if reply.kind == kind:
                return reply
            if reply.value != elliptec.BUSY:
                raise self._status_error(reply.value, what)
            failure = DeviceBusy(f"{what!r}: busy, {self.retries + 1} attempts", self.name, elliptec.BUSY)
            self._wait_until_idle()
        raise failure

    def _status_error(self, code: int, what: str) -> RigError:
        error_class = {elliptec.COMMUNICATION_TIMEOUT: CommunicationError,
                       elliptec.COMMAND_ERROR: CommunicationError, elliptec.BUSY: DeviceBusy}.get(code, MotionError)
        return error_class(f"{what}: {elliptec.status_name(code)}", self.name, code)

    def _send(self, command: bytes) -> None:
        if self._port is None:
            raise CommunicationError("the port is closed", self.name)
        try:
            self._port.reset_input_buffer()     # a late reply to an earlier command must not answer this one
            self._port.write(command)
        except _PORT_ERRORS as exc:
            raise CommunicationError(f"port lost sending {command!r}: {exc}", self.name) from exc

    def _read_reply(self, timeout: float, kinds: tuple[str, ...]) -> elliptec.Reply:
        """The next reply of one of ``kinds`` from this module. Well-formed lines of another kind or
        address are late replies to earlier commands (a move's ``PO`` that ends while ``gs`` is
        polled) or another module's: skipped, not counted as errors."""
        deadline = self._clock.now() + timeout
        try:
            while True:
                line = self._read_line(deadline, timeout)
                try:
                    reply = elliptec.decode_reply(line)
                except ValueError as exc:
                    self._resync()
                    raise _NoValidReply(f"garbled reply {line!r} ({exc})") from exc
                if reply.address == self.address and reply.kind in kinds:
                    return reply
        except _PORT_ERRORS as exc:
            raise CommunicationError(f"port lost waiting for a reply: {exc}", self.name) from exc

    def _read_line(self, deadline: float, timeout: float) -> bytes:
        line = bytearray()
        while not line.endswith(b"\n"):
            if self._clock.now() >= deadline:
                if line:
                    self._resync()
                    raise _NoValidReply(f"truncated reply {bytes(line)!r}")
                raise _NoValidReply(f"no reply within {timeout} s")
            line += self._port.read(1)
        return bytes(line)

    def _resync(self) -> None:
        """Drop what is still arriving of a broken reply, until the line is quiet for a read timeout
        (bounded: a line that never goes quiet is left to the next command's flush)."""
        deadline = self._clock.now() + self.timeout
        while self._port.read(64) and self._clock.now() < deadline:
            pass
