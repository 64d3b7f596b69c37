"""A simulated Thorlabs ELL14 rotation mount behind ``ell14sim://NAME[?option=value...]``.

It speaks the byte protocol of :mod:`mi_nest.rig.elliptec` with the timing
that matters to a driver: a move is answered only when it has finished (the
``PO`` reply appears after simulated time passes), commands that would start
another motion while it moves are refused with ``GS09``, and faults seen on
real rigs can be injected (see :meth:`SimulatedELL14.inject`).

Choices where the manual leaves the behaviour open, made so that a driver
that works here also works on the real mount:

* positions are reported on one revolution, ``0 <= counts < pulses``;
* ``ma`` accepts only targets on that revolution (others: ``GS04``) and
  turns the plain numeric way, not through zero; ``mr`` may cross zero;
* homing turns to count 0 in the asked direction (home offset 0);
* a command left incomplete for longer than :data:`MESSAGE_GAP` is dropped
  with ``GS01`` (communication time out), as the module resynchronises on gaps.

URL options: ``address`` (hex digit, default 0), ``seconds_per_turn``
(default 1.5), ``pulses`` (counts per revolution reported by ``in``, default
143360), ``type`` (ELL type in hex, default 0E), ``serial`` (8 characters).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

from .. import elliptec
from . import SimulatedDevice, SimulatedPort

MESSAGE_GAP = 0.05


@dataclass
class _Motion:
    started: float
    start: int          # counts, not wrapped, so a motion crossing zero interpolates correctly
    travel: int         # signed counts the mount will really cover
    duration: float
    ending: str         # "done" (PO), "stall" (GS02) or "disconnect" (the cable goes, no reply)

    def position_at(self, time: float) -> int:
        fraction = 1.0 if self.duration <= 0 else min(1.0, (time - self.started) / self.duration)
        return self.start + round(self.travel * fraction)


class SimulatedELL14(SimulatedDevice):
    """Faults (``inject(name, count, **details)``): ``no_reply`` (swallow the next command),
    ``busy`` (answer ``GS09`` to the next command), ``dropped_byte`` (the next reply loses
    the byte at ``index``, default the middle one), and for the next move:
    ``mechanical_timeout`` (stops halfway, ``GS02``), ``position_offset`` (ends
    ``counts`` off target) and ``disconnect_mid_move`` (stops halfway, the device disconnects).
    """

    def __init__(self, name, options):
        super().__init__(name, options)
        self.address = elliptec.check_address(options.get("address", "0"))
        self.pulses = int(options.get("pulses", 143360))
        self.seconds_per_turn = float(options.get("seconds_per_turn", 1.5))
        self.info = elliptec.Info(
            ell_type=int(options.get("type", "0E"), 16), serial_number=options.get("serial", "11400123"),
            year=2023, firmware="17", hardware=0x01, travel=360, pulses_per_unit=self.pulses)
        self.position = 0
        self.motion = None
        self._input_since = None

    @property
    def moving(self) -> bool:
        return self.motion is not None

    def current_position(self) -> float:
        """Where the mount is now, on one revolution (a test's view of the truth)."""
        if self.motion is None:
            return self.position
        return self.motion.position_at(self.clock.now()) % self.pulses

    def receive(self, data: bytes) -> None:
        self.poll()     # time acts first: a move that has just ended answers before the next command
        super().receive(data)

    def frames(self) -> Iterator[bytes]:
        while self.input:
            if self.input[:1] in (b"\r", b"\n"):   # hosts that terminate commands with CR LF are tolerated
                del self.input[:1]
                continue
            if len(self.input) < 3:
                break
            name = self.input[1:3].decode("ascii", errors="replace")
            if name in elliptec.COMMAND_DATA_LENGTHS:
                length = 3 + elliptec.COMMAND_DATA_LENGTHS[name]
            else:   # an unknown command has unknown length: it ends where this burst of bytes ends
                length = next((i for i, byte in enumerate(self.input) if byte in b"\r\n"), len(self.input))
            if len(self.input) < length:
                break
            message = bytes(self.input[:length])
            del self.input[:length]
            yield message
        if not self.input:
            self._input_since = None
        elif self._input_since is None:
            self._input_since = self.clock.now()

    def handle(self, message: bytes) -> bytes:
        if message[:1].decode("ascii", errors="replace").upper() != self.address:
            return b""     # addressed to another module on the bus
        if self.take_fault("no_reply"):
            return b""
        if self.take_fault("busy"):
            return self._reply("GS", elliptec.BUSY)
        try:
            command = elliptec.decode_command(message)
        except ValueError:
            return self._reply("GS", elliptec.COMMAND_ERROR)
        if command.name == "in":
            return self._reply("IN", self.info)
        if command.name == "gs":
            return self._reply("GS", elliptec.BUSY if self.moving else elliptec.OK)
        if command.name == "gp":
            return self._reply("PO", self.current_position())
        if self.moving:
            return self._reply("GS", elliptec.BUSY)
        if command.name == "ho":
            clockwise_distance = (self.pulses - self.position) % self.pulses
            return self._start(clockwise_distance if command.value == 0 else -self.position)
        if command.name == "ma":
            if not 0 <= command.value < self.pulses:
                return self._reply("GS", elliptec.VALUE_OUT_OF_RANGE)
            return self._start(command.value - self.position)
        return self._start(command.value)

    def _start(self, travel):
        ending = "done"
        fault = self.take_fault("mechanical_timeout", "disconnect_mid_move", "position_offset")
        if fault is not None:
            name, details = fault
            if name == "position_offset":
                travel += int(details.get("counts", 0))
            else:
                travel = int(travel / 2)
                ending = "stall" if name == "mechanical_timeout" else "disconnect"
        duration = abs(travel) / self.pulses * self.seconds_per_turn
        self.motion = _Motion(self.clock.now(), self.position, travel, duration, ending)
        return b""

    def poll(self) -> None:
        now = self.clock.now()
        if self._input_since is not None and now - self._input_since > MESSAGE_GAP:
            ours = self.input[:1].decode("ascii", errors="replace").upper() == self.address
            self.input.clear()
            self._input_since = None
            if ours:
                self.output += self._reply("GS", elliptec.COMMUNICATION_TIMEOUT)
        motion = self.motion
        if motion is None or now < motion.started + motion.duration:
            return
        self.motion = None
        self.position = (motion.start + motion.travel) % self.pulses
        if motion.ending == "disconnect":
            self.disconnected = True
            self.output.clear()
        elif motion.ending == "stall":
            self.output += self._reply("GS", elliptec.MECHANICAL_TIMEOUT)
        else:
            self.output += self._reply("PO", self.position)

    def _reply(self, kind, value):
        data = elliptec.encode_reply(elliptec.Reply(self.address, kind, value))
        fault = self.take_fault("dropped_byte")
        if fault is not None:
            index = fault[1].get("index", len(data) // 2) % len(data)
            data = data[:index] + data[index + 1:]
        return data


class Serial(SimulatedPort):
    scheme = "ell14sim"
    device_class = SimulatedELL14
