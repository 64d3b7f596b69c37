"""Byte-exact codec of the Thorlabs Elliptec ELLx serial protocol, with no I/O.

The driver (:mod:`mi_nest.rig.ell14`) and the simulated mount
(:mod:`mi_nest.rig.sim.protocol_ell14sim`) both speak through these
functions, and the tests pin them to fixed bytes, so the two sides cannot
agree on a wrong encoding. Host commands are ``<addr><cmd>[data]`` with a
one hex digit address and a two lower case letter command, no terminator;
replies are ``<addr><REPLY>[data]\\r\\n``. Numbers are upper case hex;
positions are signed 32-bit counts in two's complement (-1 is ``FFFFFFFF``).
Source: Thorlabs "ELLx modules protocol manual" (Issue 5 onwards).
"""
from __future__ import annotations

from dataclasses import dataclass

ADDRESSES = "0123456789ABCDEF"
ELL14_TYPE = 0x0E
TERMINATOR = b"\r\n"

OK, COMMUNICATION_TIMEOUT, MECHANICAL_TIMEOUT, COMMAND_ERROR, VALUE_OUT_OF_RANGE = 0, 1, 2, 3, 4
BUSY = 9
STATUS_NAMES = {
    0: "ok", 1: "communication time out", 2: "mechanical time out", 3: "command error or not supported",
    4: "value out of range", 5: "module isolated", 6: "module out of isolation", 7: "initialising error",
    8: "thermal error", 9: "busy", 10: "sensor error", 11: "motor error", 12: "out of range",
    13: "over current error",
}

# Data characters after the command letters: commands are not terminated, so
# the module (and the simulator) frames them by these lengths.
COMMAND_DATA_LENGTHS = {"in": 0, "gs": 0, "gp": 0, "ho": 1, "ma": 8, "mr": 8}
REPLY_DATA_LENGTHS = {"IN": 30, "GS": 2, "PO": 8}
_HEX_DIGITS = set("0123456789ABCDEF")


def status_name(code: int) -> str:
    return STATUS_NAMES.get(code, f"unknown status {code}")


def check_address(address: str) -> str:
    if not isinstance(address, str) or len(address) != 1 or address.upper() not in ADDRESSES:
        raise ValueError(f"Elliptec address must be one hex digit '0'-'F', got {address!r}")
    return address.upper()


def _hex(text: str, digits: int, what: str) -> int:
    if len(text) != digits or not set(text) <= _HEX_DIGITS:
        raise ValueError(f"{what} must be {digits} upper case hex digits, got {text!r}")
    return int(text, 16)


def _unsigned_hex(value: int, digits: int, what: str) -> str:
    if not 0 <= value < 16 ** digits:
        raise ValueError(f"{what} {value} does not fit in {digits} hex digits")
    return f"{value:0{digits}X}"


def encode_counts(counts: int) -> str:
    """Signed 32-bit counts as 8 hex digits, two's complement."""
    if not -2**31 <= counts < 2**31:
        raise ValueError(f"position {counts} counts is outside the signed 32-bit range")
    return f"{counts & 0xFFFFFFFF:08X}"


def decode_counts(text: str) -> int:
    value = _hex(text, 8, "position")
    return value - 2**32 if value >= 2**31 else value


# Host commands ----------------------------------------------------------

def get_info(address: str) -> bytes:
    return f"{check_address(address)}in".encode("ascii")


def get_status(address: str) -> bytes:
    return f"{check_address(address)}gs".encode("ascii")


def get_position(address: str) -> bytes:
    return f"{check_address(address)}gp".encode("ascii")


def home(address: str, clockwise: bool = True) -> bytes:
    return f"{check_address(address)}ho{0 if clockwise else 1}".encode("ascii")


def move_absolute(address: str, counts: int) -> bytes:
    return f"{check_address(address)}ma{encode_counts(counts)}".encode("ascii")


def move_relative(address: str, counts: int) -> bytes:
    return f"{check_address(address)}mr{encode_counts(counts)}".encode("ascii")


@dataclass(frozen=True)
class Command:
    """A host command as the module reads it; ``value`` is counts, or 0/1 (clockwise/counter) for ``ho``."""
    address: str
    name: str
    value: int | None = None


def decode_command(message: bytes) -> Command:
    text = message.decode("ascii", errors="replace")
    if len(text) < 3:
        raise ValueError(f"command too short: {message!r}")
    address, name, data = check_address(text[0]), text[1:3], text[3:]
    if name not in COMMAND_DATA_LENGTHS:
        raise ValueError(f"unknown command {name!r} in {message!r}")
    if len(data) != COMMAND_DATA_LENGTHS[name]:
        raise ValueError(f"command {name!r} takes {COMMAND_DATA_LENGTHS[name]} data characters, got {data!r}")
    if name == "ho":
        if data not in ("0", "1"):
            raise ValueError(f"home direction must be '0' (clockwise) or '1', got {data!r}")
        return Command(address, name, int(data))
    return Command(address, name, decode_counts(data) if data else None)


# Replies -----------------------------------------------------------------

@dataclass(frozen=True)
class Info:
    """The ``IN`` record. For the ELL14, ``pulses_per_unit`` is counts per revolution."""
    ell_type: int
    serial_number: str
    year: int
    firmware: str
    hardware: int
    travel: int
    pulses_per_unit: int

    @property
    def imperial_thread(self) -> bool:
        return bool(self.hardware & 0x80)

    @property
    def hardware_revision(self) -> int:
        return self.hardware & 0x7F


@dataclass(frozen=True)
class Reply:
    """One reply line: ``kind`` 'PO' (value: counts), 'GS' (value: status code) or 'IN' (value: :class:`Info`)."""
    address: str
    kind: str
    value: int | Info

    @property
    def status_name(self) -> str:
        return status_name(self.value)


def encode_reply(reply: Reply) -> bytes:
    address = check_address(reply.address)
    if reply.kind == "PO":
        data = encode_counts(reply.value)
    elif reply.kind == "GS":
        data = _unsigned_hex(reply.value, 2, "status code")
    elif reply.kind == "IN":
        info = reply.value
        if len(info.serial_number) != 8 or not (info.serial_number.isascii() and info.serial_number.isalnum()):
            raise ValueError(f"serial number must be 8 letters or digits, got {info.serial_number!r}")
        if not 0 <= info.year <= 9999:
            raise ValueError(f"year {info.year} does not fit in 4 digits")
        _hex(info.firmware, 2, "firmware")
        data = (_unsigned_hex(info.ell_type, 2, "type") + info.serial_number + f"{info.year:04d}" + info.firmware
                + _unsigned_hex(info.hardware, 2, "hardware") + _unsigned_hex(info.travel, 4, "travel")
                + _unsigned_hex(info.pulses_per_unit, 8, "pulses per unit"))
    else:
        raise ValueError(f"unknown reply kind {reply.kind!r}")
    return f"{address}{reply.kind}{data}".encode("ascii") + TERMINATOR


def decode_reply(line: bytes) -> Reply:
    """Parse one reply line including its CR LF; anything malformed raises ValueError."""
    if not line.endswith(TERMINATOR):
        raise ValueError(f"reply does not end with CR LF: {line!r}")
    body = line[:-len(TERMINATOR)]
    if not body.isascii() or len(body) < 3:
        raise ValueError(f"reply is not an ASCII '<addr><KIND>...' line: {line!r}")
    text = body.decode("ascii")
    address, kind, data = check_address(text[0]), text[1:3], text[3:]
    if kind not in REPLY_DATA_LENGTHS:
        raise ValueError(f"unknown reply kind {kind!r} in {line!r}")
    if len(data) != REPLY_DATA_LENGTHS[kind]:
        raise ValueError(f"{kind} reply needs {REPLY_DATA_LENGTHS[kind]} data characters, got {len(data)}: "
                         f"{line!r}")
    if kind == "PO":
        return Reply(address, kind, decode_counts(data))
    if kind == "GS":
        return Reply(address, kind, _hex(data, 2, "status code"))
    serial_number, year, firmware = data[2:10], data[10:14], data[14:16]
    if not (serial_number.isalnum() and year.isdigit()):
        raise ValueError(f"IN reply has a malformed serial number or year: {line!r}")
    _hex(firmware, 2, "firmware")
    return Reply(address, kind, Info(
        ell_type=_hex(data[0:2], 2, "type"), serial_number=serial_number, year=int(year), firmware=firmware,
        hardware=_hex(data[16:18], 2, "hardware"), travel=_hex(data[18:22], 4, "travel"),
        pulses_per_unit=_hex(data[22:30], 8, "pulses per unit")))
