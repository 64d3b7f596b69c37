"""Driver for the polariscope's Thorlabs HDR50 rotation stages (azimuth, elevation) on KST101/KST201/BSC201 controllers.

APT has no checksum and does not acknowledge motion commands, so the driver
believes only what it reads back: every move ends with a read of the position
counter (MOT_REQ_POSCOUNTER) compared with the target; a move that did not
arrive is sent once more and then reported. Requests that change nothing
(status, position, identity) are retried after flushing the stream; a motion
command is never repeated before the position has been read back. A motion
is followed through its completion message or, if that is lost, through the
status bits; one whose counter stops changing is stopped and reported as
stalled.

Everything waits on ``clock_of(port)``, so against the simulator
(``aptsim://NAME``) a motion of seconds costs no real time, and a real
controller is driven by changing only the URL (``/dev/ttyUSB0``).
"""
from __future__ import annotations

import logging
import warnings
from collections import deque

import serial

from . import apt
from .clock import clock_of
from .errors import CommunicationError, DeviceBusy, MotionError

log = logging.getLogger(__name__)

COUNTS_PER_REVOLUTION = 200 * 2048 * 66   # microsteps: 200 full steps x 2048 microsteps x 66:1 worm
BAUDRATE = 115200
COMPLETIONS = (apt.MoveCompleted, apt.MoveHomed, apt.MoveStopped)


class HDR50:
    """One HDR50 stage on channel ``channel`` of an APT stepper controller at ``url``.

    ``timeout``: seconds to wait for each reply; ``retries``: further attempts
    of a request that went unanswered; ``tolerance``: microsteps the position
    read back may differ from the target; ``poll_interval``: seconds between
    status checks while a motion runs; ``stall_timeout``: seconds without
    progress after which a motion counts as stalled; ``busy_timeout``: seconds
    to wait for a motion someone else started before :class:`DeviceBusy`.
    """

    def __init__(self, url, channel=1, timeout=1.0, retries=2, tolerance=10, poll_interval=0.1,
                 stall_timeout=2.0, busy_timeout=30.0, motion_timeout=120.0, port_factory=serial.serial_for_url):
        self.url, self.name = url, f"HDR50 at {url}"
        self.timeout, self.retries, self.tolerance = timeout, retries, tolerance
        self.poll_interval, self.stall_timeout, self.busy_timeout = poll_interval, stall_timeout, busy_timeout
        # A full turn takes 36 s at the HDR50's 10 deg/s: a motion still running after this has run away.
        self.motion_timeout = motion_timeout
        self._framer = apt.Framer()
        self._completions = deque()
        try:
            self._port = port_factory(url, baudrate=BAUDRATE, bytesize=serial.EIGHTBITS, parity=serial.PARITY_NONE,
                                      stopbits=serial.STOPBITS_ONE, rtscts=True, timeout=poll_interval)
        except (OSError, ValueError) as exc:
            raise CommunicationError(f"cannot open the port: {exc}", device=self.name) from exc
        self.clock = clock_of(self._port)
        try:
            self._reset_link()
            self.address, self.info = self._probe()
            # a single USB unit takes motor messages itself; in a rack, the card in the channel's bay does
            self._dest, self._channel = ((apt.USB_UNIT, channel) if self.address == apt.USB_UNIT
                                         else (apt.bay(channel), 1))
            self.name = f"HDR50 on {self.info.model} #{self.info.serial_number} ({url})"
            self._send(apt.NoFlashProgramming(dest=self.address))
            self._send(apt.StopUpdateMessages(dest=self._dest))
            self._enable()
        except BaseException:
            self._port.close()
            raise

    # --- public ----------------------------------------------------------------------------------
    def home(self) -> float:
        """Home the stage (it turns CCW to its home switch); return the measured position in degrees."""
        def homed() -> tuple[bool, str]:
            bits = self.status()
            return bool(bits & apt.HOMED), f"homing ended without the homed flag ({apt.describe_status(bits)})"
        self._perform(apt.MoveHome(self._channel, dest=self._dest), apt.MoveHomed, homed)
        return self.position()

    def move_to(self, degrees: float) -> float:
        """Move to ``degrees`` (absolute, not wrapped: 370 is one turn past 10) and return the measured position."""
        target = round(degrees * COUNTS_PER_REVOLUTION / 360)
        measured = None

        def arrived() -> tuple[bool, str]:
            nonlocal measured
            measured = self._counter()
            return (abs(measured - target) <= self.tolerance,
                    f"position read back {measured} microsteps, commanded {target} (tolerance {self.tolerance})")
        self._perform(apt.MoveAbsolute(self._channel, target, dest=self._dest), apt.MoveCompleted, arrived)
        return measured * 360 / COUNTS_PER_REVOLUTION

    def position(self) -> float:
        """The position counter, in degrees."""
        return self._counter() * 360 / COUNTS_PER_REVOLUTION

    def status(self) -> int:
        """The channel's status bits (``mi_nest.rig.apt`` names them; ``apt.describe_status`` spells them out)."""
        return self._request(apt.ReqStatusBits(self._channel, dest=self._dest), apt.GetStatusBits).status

    def close(self) -> None:
        self._port.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # --- link --------------------------------------------------------------------------------------
    def _reset_link(self):
        """The reset the protocol document asks for (dwell, purge, dwell, RTS), in pylablib's order:
        RTS up, purge, RTS down. Adapters and ptys that have no RTS line only lose the toggle."""
        try:
            self._port.rts = True
        except (OSError, ValueError) as exc:
            warnings.warn(f"{self.name}: cannot set RTS ({exc}); continuing without the RTS toggle", RuntimeWarning)
        self.clock.sleep(0.05)
        self._flush()
        self._port.reset_output_buffer()
        self.clock.sleep(0.05)
        try:
            self._port.rts = False
        except (OSError, ValueError):
            pass    # already warned above
        self.clock.sleep(0.05)

    def _probe(self):
        """(address, HW_GET_INFO) of the controller: a USB unit answers on 0x50, a rack's motherboard on 0x11."""
        for _ in range(self.retries + 1):
            for address in (apt.USB_UNIT, apt.RACK):
                self._send(apt.ReqInfo(dest=address))
                info = self._receive(lambda m: isinstance(m, apt.GetInfo) and m.source == address, self.timeout)
                if info:
                    return address, info
            self._flush()
        raise CommunicationError(f"no APT controller answered HW_REQ_INFO on 0x50 or 0x11 "
                                 f"({self.retries + 1} rounds of {self.timeout} s)", device=self.name)

    def _send(self, message):
        try:
            self._port.write(apt.encode(message))
        except OSError as exc:
            raise CommunicationError(f"serial link lost: {exc}", device=self.name) from exc

    def _flush(self):
        """Drop everything received and half-framed: after a garbled or unanswered exchange the
        stream may be out of step, and the next request starts clean."""
        try:
            self._port.reset_input_buffer()
        except OSError as exc:
            raise CommunicationError(f"serial link lost: {exc}", device=self.name) from exc
        self._framer.clear()

    def _receive(self, wanted, timeout):
        """The first message for which ``wanted`` is true, within ``timeout`` seconds, else None.
        Completion messages that arrive meanwhile are kept for :meth:`_await_motion`."""
        for message in self._completions:
            if wanted(message):
                self._completions.remove(message)
                return message
        deadline = self.clock.now() + timeout
        while True:
            try:
                for frame in self._framer.frames():
                    message = self._accept(frame)
                    if message is None:
                        continue
                    if wanted(message):
                        return message
                    if isinstance(message, COMPLETIONS):
                        self._completions.append(message)
            except ValueError as exc:
                log.warning("%s: %s; the framer dropped its buffer", self.name, exc)
            if self.clock.now() >= deadline:
                return None
            try:
                self._framer.feed(self._port.read(max(1, self._port.in_waiting)))
            except OSError as exc:
                raise CommunicationError(f"serial link lost: {exc}", device=self.name) from exc

    def _accept(self, frame):
        """The message in ``frame`` if it is one for the host we understand; a device error report raises."""
        try:
            message = apt.decode(frame)
        except ValueError as exc:
            log.info("%s: ignoring frame %s (%s)", self.name, frame.hex(" "), exc)
            return None
        if message.dest != apt.HOST:
            return None
        if isinstance(message, apt.HwRichResponse):
            raise CommunicationError(f"controller reported an error about message 0x{message.failed_message:04X}: "
                                     f"{message.notes}", device=self.name, code=message.code)
        if isinstance(message, apt.HwResponse):
            raise CommunicationError("controller reported an error event (HW_RESPONSE)", device=self.name)
        return message

    def _from_channel(self, message):
        return message.source == self._dest and getattr(message, "channel", self._channel) == self._channel

    def _request(self, message, reply_type):
        """Send a request that changes nothing and return its reply, flushing and asking again when none comes."""
        for attempt in range(self.retries + 1):
            if attempt:
                log.warning("%s: no %s, asking again", self.name, reply_type.__name__)
                self._flush()
            self._send(message)
            reply = self._receive(lambda m: isinstance(m, reply_type) and self._from_channel(m), self.timeout)
            if reply:
                return reply
        raise CommunicationError(f"no {reply_type.__name__} reply to {type(message).__name__} after "
                                 f"{self.retries + 1} attempts of {self.timeout} s", device=self.name)

    def _counter(self):
        return self._request(apt.ReqPositionCounter(self._channel, dest=self._dest), apt.GetPositionCounter).position

    # --- motion ------------------------------------------------------------------------------------
    def _enable(self):
        for _ in range(self.retries + 1):
            self._send(apt.SetChannelEnableState(self._channel, apt.ENABLE, dest=self._dest))
            bits = self.status()
            if bits & apt.ENABLED:
                return
        raise MotionError(f"channel {self._channel} did not enable ({apt.describe_status(bits)})",
                          device=self.name, code=bits)

    def _prepare(self):
        """Wait out a motion someone else started (front panel, another program), enable the channel if it
        was disabled behind our back, and forget completions of earlier motions."""
        deadline = self.clock.now() + self.busy_timeout
        while (bits := self.status()) & apt.MOTION:
            if self.clock.now() >= deadline:
                raise DeviceBusy(f"still moving after {self.busy_timeout} s ({apt.describe_status(bits)})",
                                 device=self.name, code=bits)
            self.clock.sleep(self.poll_interval)
        if not bits & apt.ENABLED:
            self._enable()
        self._completions.clear()

    def _perform(self, command, done_type, arrived):
        """Send a motion command, follow it to its end, and check ``arrived()`` -> (ok, problem).
        A motion that did not arrive is commanded once more, then reported."""
        for attempt in range(2):
            self._prepare()
            self._send(command)
            self._await_motion(done_type)
            ok, problem = arrived()
            if ok:
                return
            if not attempt:
                log.warning("%s: %s; commanding the motion once more", self.name, problem)
        bits = self.status()
        raise MotionError(f"{problem}, also after commanding it again ({apt.describe_status(bits)})",
                          device=self.name, code=bits)

    def _await_motion(self, done_type):
        """Return when the motion has ended: its completion message came, or the status bits say it is over
        (the message can be lost). A counter that stops changing for stall_timeout means a stall."""
        last_position, last_change = None, self.clock.now()
        deadline = last_change + self.motion_timeout
        while self._receive(lambda m: isinstance(m, done_type) and self._from_channel(m), self.poll_interval) is None:
            if not self.status() & apt.MOTION:
                return
            position, now = self._counter(), self.clock.now()
            if now > deadline:
                self._request(apt.MoveStop(self._channel, apt.STOP_IMMEDIATE, dest=self._dest), apt.MoveStopped)
                bits = self.status()
                raise MotionError(f"stage still moving at {position} microsteps after {self.motion_timeout} s; "
                                  f"stopped it ({apt.describe_status(bits)})", device=self.name, code=bits)
            if position != last_position:
                last_position, last_change = position, now
            elif now - last_change >= self.stall_timeout:
                self._request(apt.MoveStop(self._channel, apt.STOP_IMMEDIATE, dest=self._dest), apt.MoveStopped)
                bits = self.status()
                raise MotionError(f"stage stalled at {position} microsteps: no progress for {self.stall_timeout} s "
                                  f"and no completion; stopped it ({apt.describe_status(bits)})",
                                  device=self.name, code=bits)
