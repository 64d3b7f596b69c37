"""Simulated Thorlabs stepper controller (KST201, KST101 or BSC201) driving an HDR50 rotation stage: ``aptsim://NAME``.

The rig's HDR50 stages are built and tested against this twin before anyone
has the hardware, so it speaks the APT protocol byte for byte (through
:mod:`mi_nest.rig.apt`) and keeps the state a real controller keeps: enable
state, homed flag, position counter, and motions that take simulated time.

URL options:

* ``model`` -- ``KST201`` (default), ``KST101`` or ``BSC201``, reported by HW_GET_INFO.
* ``address`` -- ``0x50`` (default): a single USB unit answering everything on 0x50.
  ``0x11``: a rack unit whose motherboard answers hardware messages on 0x11 and
  whose channel card sits at bay 0x21 (the addressing pylablib and
  thorlabs-apt-device use for BSC20x units); nothing answers on 0x50.
* ``speed`` -- degrees per second for moves and homing (default 10).
* ``angle`` -- how far (degrees, CW) the stage sits from its home switch at power-up (default 37.5).
* ``serial`` -- serial number reported by HW_GET_INFO.

Behaviour decisions (real controllers are silent in these cases; none sends an error):

* The channel powers up disabled and not homed, counter 0. Motion commands
  are ignored while it is disabled; disabling during a motion de-energises the
  motor, which stops where it is without a completion message.
* A motion command that arrives while a motion runs is ignored; the running
  motion finishes and sends its own MOVE_COMPLETED.
* Homing runs CCW to the nearest home-switch crossing (the HDR50 turns without
  end stops), then sets the counter to 0 and the homed flag, and sends MOVE_HOMED.
* A message for another address is ignored; a message it does not know
  (or cannot decode) is answered with HW_RESPONSE, as a BSC201 was seen doing.

Faults (``device.inject(name, count, **details)``), consumed in queue order:

* ``no_reply`` -- the next message received is lost: no action, no reply.
* ``dropped_byte`` -- the next message sent loses its middle byte.
  Both take ``message=ID`` to wait for a message with that id (e.g. ``apt.MoveAbsolute.ID``).
* ``busy`` -- the next motion command finds a motion still running (as if
  started from the front panel, for ``seconds``, default 1, CW) and is ignored.
* ``mechanical_timeout`` -- the next motion stalls a third of the way: the
  moving bits stay set, the counter stops, no completion until MOVE_STOP.
* ``disconnect_mid_move`` -- the USB link drops halfway through the next motion.
  A K-cube is powered separately, so the motion runs to its end and its
  completion message is lost; after ``device.disconnected = False`` a reopen
  finds the stage at its target.
* ``position_offset`` (``counts=n``) -- the next motion ends ``n`` microsteps past
  its target, and the counter says so.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

from .. import apt
from . import SimulatedDevice, SimulatedPort

COUNTS_PER_REVOLUTION = 200 * 2048 * 66   # full steps x microsteps x worm ratio
COUNTS_PER_DEGREE = COUNTS_PER_REVOLUTION / 360
MODELS = {"KST201": 26000201, "KST101": 26000101, "BSC201": 40000201}   # model: default serial number
MOTION_FAULTS = ("busy", "mechanical_timeout", "disconnect_mid_move", "position_offset")


@dataclass
class Motion:
    kind: str            # "move", "home", or "other" (a motion the host did not command)
    start: float         # counter value at t0
    target: int          # where the counter ends
    t0: float
    counts_per_second: float
    zero: int = 0        # subtracted from the counter when the motion ends (homing resets it)
    stall_at: float | None = None
    disconnect_at: float | None = None
    silent: bool = False  # its completion message is lost

    @property
    def end(self) -> float:
        return self.t0 + abs(self.target - self.start) / self.counts_per_second

    def position(self, now: float) -> float:
        stop = self.target if self.stall_at is None else self.stall_at
        travelled = self.counts_per_second * max(0.0, now - self.t0)
        return self.start + math.copysign(min(abs(stop - self.start), travelled), stop - self.start)


class SimulatedStepperController(SimulatedDevice):
    def __init__(self, name, options):
        super().__init__(name, options)
        self.model = options.get("model", "KST201")
        if self.model not in MODELS:
            raise ValueError(f"aptsim://{name}: model must be one of {sorted(MODELS)}, got {self.model!r}")
        self.serial_number = int(options.get("serial", MODELS[self.model]))
        self.address = int(options.get("address", "0x50"), 0)
        self.channel_address = apt.bay(1) if self.address == apt.RACK else self.address
        self.counts_per_second = float(options.get("speed", 10)) * COUNTS_PER_DEGREE
        # counter value at which the home switch sits (the stage powers up `angle` degrees CW of it)
        self.home_switch = -round(float(options.get("angle", 37.5)) * COUNTS_PER_DEGREE)
        self.counter = 0
        self.enabled = False
        self.homed = False
        self.motion = None
        self.framer = apt.Framer()

    # --- state -----------------------------------------------------------------------------------
    def position(self) -> float:
        """The counter now (a fraction of a microstep while moving)."""
        return self.motion.position(self.clock.now()) if self.motion else self.counter

    def status(self) -> int:
        bits = apt.MOTOR_CONNECTED | (apt.ENABLED if self.enabled else 0) | (apt.HOMED if self.homed else 0)
        if self.motion:
            bits |= apt.MOVING_CW if self.motion.target >= self.motion.start else apt.MOVING_CCW
            bits |= apt.HOMING if self.motion.kind == "home" else 0
        return bits

    def poll(self) -> None:
        motion, now = self.motion, self.clock.now()
        if motion is None:
            return
        if motion.disconnect_at is not None and now >= motion.disconnect_at and not motion.silent:
            motion.silent, self.disconnected = True, True
            self.output.clear()
        if motion.stall_at is None and now >= motion.end:
            self.motion = None
            self.counter = motion.target - motion.zero
            self.home_switch -= motion.zero
            self.homed = self.homed or motion.kind == "home"
            if not motion.silent:
                reply = dict(dest=apt.HOST, source=self.channel_address)
                done = (apt.MoveHomed(1, **reply) if motion.kind == "home" else
                        apt.MoveCompleted(1, self.counter, 0, self.status(), **reply))
                self.output += self._send(done)

    def _stop_here(self):
        self.counter, self.motion = round(self.position()), None

    # --- the wire --------------------------------------------------------------------------------
    def frames(self) -> Iterator[bytes]:
        self.framer.feed(self.input)
        self.input.clear()
        try:
            yield from self.framer.frames()
        except ValueError:
            pass    # garbage: the framer dropped it; a real controller resynchronises the same silent way

    def _take_fault(self, name, message_id):
        """The next fault if it is ``name`` and, where it names a ``message`` id, this message has it."""
        if self.faults and self.faults[0][0] == name and self.faults[0][1].get("message", message_id) == message_id:
            return self.take_fault(name)
        return None

    def _send(self, message):
        data = apt.encode(message)
        if self._take_fault("dropped_byte", message.ID):
            data = data[:len(data) // 2] + data[len(data) // 2 + 1:]
        return data

    def handle(self, frame: bytes) -> bytes:
        self.poll()
        header = apt.parse_header(frame)
        if self.disconnected or self._take_fault("no_reply", header.message_id):
            return b""
        if header.dest not in (self.address, self.channel_address):
            return b""
        try:
            message = apt.decode(frame)
        except ValueError:
            return self._send(apt.HwResponse(dest=apt.HOST, source=header.dest))
        reply = self._respond(message)
        return b"" if reply is None else self._send(reply)

    def _respond(self, message):
        source = message.dest
        if isinstance(message, apt.ReqInfo):
            return apt.GetInfo(self.serial_number, self.model, 16, 0x03000B, "HDR50 rotation stage (simulated)",
                               3, 1, 1, dest=apt.HOST, source=source)
        if isinstance(message, (apt.NoFlashProgramming, apt.StopUpdateMessages)):
            return None
        channel = getattr(message, "channel", None)
        if channel is None:     # a hardware message only a host receives
            return apt.HwResponse(dest=apt.HOST, source=source)
        if channel != 1 or message.dest != self.channel_address:
            return None         # no such channel here (a rack's motherboard drives no motor)
        if isinstance(message, apt.SetChannelEnableState):
            if message.state == apt.DISABLE and self.motion:
                self._stop_here()
            self.enabled = message.state == apt.ENABLE
        elif isinstance(message, apt.ReqStatusBits):
            return apt.GetStatusBits(1, self.status(), dest=apt.HOST, source=source)
        elif isinstance(message, apt.ReqPositionCounter):
            return apt.GetPositionCounter(1, round(self.position()), dest=apt.HOST, source=source)
        elif isinstance(message, apt.MoveStop):
            if self.motion:
                self._stop_here()
            return apt.MoveStopped(1, self.counter, 0, self.status(), dest=apt.HOST, source=source)
        elif isinstance(message, (apt.MoveAbsolute, apt.MoveRelative, apt.MoveHome)):
            self._start(message)
        else:
            return apt.HwResponse(dest=apt.HOST, source=source)
        return None

    def _start(self, command):
        now, here = self.clock.now(), self.position()
        fault = self.take_fault(*MOTION_FAULTS)
        name, details = fault if fault else (None, {})
        if name == "busy" and self.motion is None:
            self.motion = Motion("other", here, round(here + details.get("seconds", 1.0) * self.counts_per_second),
                                 now, self.counts_per_second)
        if self.motion is not None or not self.enabled:
            return
        if isinstance(command, apt.MoveHome):
            turns = math.floor((here - self.home_switch) / COUNTS_PER_REVOLUTION)
            switch = self.home_switch + turns * COUNTS_PER_REVOLUTION
            motion = Motion("home", here, switch, now, self.counts_per_second, zero=switch)
            self.homed = False
        else:
            target = command.position if isinstance(command, apt.MoveAbsolute) else round(here) + command.distance
            motion = Motion("move", here, target, now, self.counts_per_second)
        if name == "position_offset":
            motion.target += details["counts"]
        elif name == "mechanical_timeout":
            motion.stall_at = motion.start + (motion.target - motion.start) / 3
        elif name == "disconnect_mid_move":
            motion.disconnect_at = (motion.t0 + motion.end) / 2
        self.motion = motion


class Serial(SimulatedPort):
    scheme = "aptsim"
    device_class = SimulatedStepperController
