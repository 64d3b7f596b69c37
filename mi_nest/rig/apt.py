"""The Thorlabs APT binary protocol as pure functions: headers, typed messages, a stream framer. No I/O.

The HDR50 driver and the simulated controller both speak through this module,
so they cannot drift apart, and the tests pin its bytes against fixtures from
the protocol document ("Host-Controller Communications Protocol") and from
independent implementations (thorlabs-apt-protocol, pylablib's kinesis.py).

Every message starts with a 6-byte little-endian header: message id (uint16),
then either two parameter bytes (short form) or the length of the data that
follows (long form, flagged by bit 0x80 of the destination byte), then the
destination and source addresses. APT has no checksum and no delimiter: a
lost byte shifts every later boundary, which is why the framer rejects
implausible lengths and the driver flushes and asks again.
"""
from __future__ import annotations

import struct
from dataclasses import astuple, dataclass, fields
from typing import ClassVar, Iterator

HOST = 0x01       # the PC
RACK = 0x11       # motherboard of a rack / benchtop unit (BSC20x): answers hardware messages
USB_UNIT = 0x50   # a single-channel USB unit (K-cube KST101/KST201): answers everything
LONG_FORM = 0x80  # flag on the destination byte: `length` data bytes follow the header
MAX_DATA = 255    # the protocol document: no data packet exceeds 255 bytes


def bay(channel: int) -> int:
    """Address of the card that drives ``channel`` in a rack unit (0x21 for channel 1)."""
    return 0x20 + channel


ENABLE, DISABLE = 0x01, 0x02        # MOD_SET_CHANENABLESTATE states
STOP_IMMEDIATE, STOP_PROFILED = 0x01, 0x02

# Status bits (P_MOT_SB_* in the protocol document); CW is the direction of increasing position.
CW_LIMIT, CCW_LIMIT = 0x01, 0x02
MOVING_CW, MOVING_CCW, JOGGING_CW, JOGGING_CCW = 0x10, 0x20, 0x40, 0x80
MOTOR_CONNECTED, HOMING, HOMED = 0x100, 0x200, 0x400
ENABLED = 0x80000000
MOTION = MOVING_CW | MOVING_CCW | JOGGING_CW | JOGGING_CCW | HOMING
_STATUS_NAMES = {CW_LIMIT: "CW limit", CCW_LIMIT: "CCW limit", MOVING_CW: "moving CW", MOVING_CCW: "moving CCW",
                 JOGGING_CW: "jogging CW", JOGGING_CCW: "jogging CCW", MOTOR_CONNECTED: "motor connected",
                 HOMING: "homing", HOMED: "homed", ENABLED: "enabled"}


def describe_status(bits: int) -> str:
    """Status bits in words, for error messages."""
    names = [name for bit, name in _STATUS_NAMES.items() if bits & bit]
    return ", ".join(names) or "idle, not homed, disabled"


_SHORT_HEADER = struct.Struct("<HBBBB")
_LONG_HEADER = struct.Struct("<HHBB")


@dataclass(frozen=True)
class Header:
    message_id: int
    dest: int          # without the long-form flag
    source: int
    long_form: bool
    param1: int = 0    # short form only
    param2: int = 0
    length: int = 0    # long form only: data bytes after the header

    def pack(self) -> bytes:
        if self.long_form:
            return _LONG_HEADER.pack(self.message_id, self.length, self.dest | LONG_FORM, self.source)
        return _SHORT_HEADER.pack(self.message_id, self.param1, self.param2, self.dest, self.source)


def parse_header(data: bytes | bytearray) -> Header:
    if len(data) < 6:
        raise ValueError(f"truncated APT header: {len(data)} of 6 bytes ({bytes(data).hex(' ')})")
    message_id, param1, param2, dest, source = _SHORT_HEADER.unpack_from(data)
    if dest & LONG_FORM:
        return Header(message_id, dest & ~LONG_FORM, source, True, length=param1 | param2 << 8)
    return Header(message_id, dest, source, False, param1, param2)


MESSAGES = {}


@dataclass(frozen=True, kw_only=True)
class Message:
    """One APT message. Subclasses declare their id and, for the long form, the struct layout of their data;
    short-form subclasses carry at most two one-byte fields, sent as the header's parameter bytes."""
    dest: int
    source: int = HOST
    ID: ClassVar[int]
    LAYOUT: ClassVar[struct.Struct | None]

    def __init_subclass__(cls, message_id, layout=None, **kwargs):
        super().__init_subclass__(**kwargs)
        cls.ID, cls.LAYOUT = message_id, layout and struct.Struct(layout)
        MESSAGES[message_id] = cls

    def values(self) -> tuple:
        return astuple(self)[2:]     # the payload fields, after dest and source


def encode(message: Message) -> bytes:
    """The bytes of ``message``; ValueError when a field does not fit its wire type."""
    values = message.values()
    try:
        if message.LAYOUT is None:
            frame = Header(message.ID, message.dest, message.source, False, *(*values, 0, 0)[:2]).pack()
        else:
            data = message.LAYOUT.pack(*(v.encode("latin-1") if isinstance(v, str) else v for v in values))
            frame = Header(message.ID, message.dest, message.source, True, length=len(data)).pack() + data
    except (struct.error, UnicodeEncodeError) as exc:
        raise ValueError(f"cannot encode {message!r}: {exc}") from None
    # struct silently truncates strings, and a destination can collide with the long-form flag
    try:
        faithful = decode(frame) == message
    except ValueError:
        faithful = False
    if not faithful:
        raise ValueError(f"cannot encode {message!r}: a field does not fit its wire format")
    return frame


def decode(frame: bytes) -> Message:
    """The typed message in one complete frame; ValueError for unknown ids, the wrong form or length."""
    header = parse_header(frame)
    cls = MESSAGES.get(header.message_id)
    if cls is None:
        raise ValueError(f"unknown APT message id 0x{header.message_id:04X}")
    name = f"{cls.__name__} (0x{cls.ID:04X})"
    if (cls.LAYOUT is not None) != header.long_form:
        raise ValueError(f"{name} must be {'long' if cls.LAYOUT else 'short'} form")
    if cls.LAYOUT is None:
        if len(frame) != 6:
            raise ValueError(f"{name} is a 6-byte message, got {len(frame)} bytes")
        values = (header.param1, header.param2)[:len(fields(cls)) - 2]
    else:
        if header.length != cls.LAYOUT.size or len(frame) != 6 + header.length:
            raise ValueError(f"{name} carries {cls.LAYOUT.size} data bytes; header says {header.length}, "
                             f"frame has {len(frame) - 6}")
        values = [v.split(b"\0", 1)[0].decode("latin-1") if isinstance(v, bytes) else v
                  for v in cls.LAYOUT.unpack_from(frame, 6)]
    return cls(*values, dest=header.dest, source=header.source)


class Framer:
    """Cuts complete frames off a byte stream that arrives in arbitrary pieces."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> None:
        self._buffer += data

    @property
    def pending(self) -> int:
        """Bytes held back because their frame is not complete yet."""
        return len(self._buffer)

    def clear(self) -> None:
        self._buffer.clear()

    def frames(self) -> Iterator[bytes]:
        """Yield each complete frame. A header announcing more than MAX_DATA bytes means the stream lost
        its alignment: the buffer is dropped and ValueError raised (frames before it were yielded)."""
        while len(self._buffer) >= 6:
            header = parse_header(self._buffer)
            if header.length > MAX_DATA:
                self._buffer.clear()
                raise ValueError(f"implausible APT frame: message 0x{header.message_id:04X} announces "
                                 f"{header.length} data bytes (stream out of step)")
            size = 6 + header.length
            if len(self._buffer) < size:
                return
            frame = bytes(self._buffer[:size])
            del self._buffer[:size]
            yield frame


# --- Hardware messages -------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReqInfo(Message, message_id=0x0005):
    pass


@dataclass(frozen=True)
class GetInfo(Message, message_id=0x0006, layout="<i8sHI48s12xHHH"):
    """84 bytes. ``firmware`` packs minor, interim, major (one byte each, low first), as pylablib reads it."""
    serial_number: int
    model: str
    hardware_type: int
    firmware: int
    notes: str
    hardware_version: int
    mod_state: int
    channels: int

    @property
    def firmware_version(self) -> str:
        return f"{self.firmware >> 16 & 0xFF}.{self.firmware >> 8 & 0xFF}.{self.firmware & 0xFF}"


@dataclass(frozen=True)
class StopUpdateMessages(Message, message_id=0x0012):
    pass


@dataclass(frozen=True)
class NoFlashProgramming(Message, message_id=0x0018):
    pass


@dataclass(frozen=True)
class HwResponse(Message, message_id=0x0080):
    """Sent unprompted when something needs attention, e.g. a message the controller does not support."""


@dataclass(frozen=True)
class HwRichResponse(Message, message_id=0x0081, layout="<HH64s"):
    failed_message: int
    code: int
    notes: str


@dataclass(frozen=True)
class SetChannelEnableState(Message, message_id=0x0210):
    channel: int
    state: int


# --- Motor messages ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReqPositionCounter(Message, message_id=0x0411):
    channel: int


@dataclass(frozen=True)
class GetPositionCounter(Message, message_id=0x0412, layout="<Hi"):
    channel: int
    position: int


@dataclass(frozen=True)
class ReqStatusBits(Message, message_id=0x0429):
    channel: int


@dataclass(frozen=True)
class GetStatusBits(Message, message_id=0x042A, layout="<HI"):
    channel: int
    status: int


@dataclass(frozen=True)
class MoveHome(Message, message_id=0x0443):
    channel: int


@dataclass(frozen=True)
class MoveHomed(Message, message_id=0x0444):
    channel: int


@dataclass(frozen=True)
class MoveRelative(Message, message_id=0x0448, layout="<Hi"):
    channel: int
    distance: int


@dataclass(frozen=True)
class MoveAbsolute(Message, message_id=0x0453, layout="<Hi"):
    channel: int
    position: int


@dataclass(frozen=True)
class MoveCompleted(Message, message_id=0x0464, layout="<HiiI"):
    """The stepper status block: channel, position, encoder count, status bits (14 bytes)."""
    channel: int
    position: int
    encoder: int
    status: int


@dataclass(frozen=True)
class MoveStop(Message, message_id=0x0465):
    channel: int
    mode: int


@dataclass(frozen=True)
class MoveStopped(Message, message_id=0x0466, layout="<HiiI"):
    channel: int
    position: int
    encoder: int
    status: int
