"""ELL14 support: the Elliptec codec byte for byte, the simulated mount, the driver against it, faults included."""
import math
import time

import numpy as np
import pytest
import serial

import mi_nest.rig  # noqa: F401  (registers ell14sim:// with pyserial)
from mi_nest.rig import elliptec, sim
from mi_nest.rig.ell14 import ELL14
from mi_nest.rig.errors import CommunicationError, DeviceBusy, MotionError, RigError
from mi_nest.rig.sim.protocol_ell14sim import MESSAGE_GAP, SimulatedELL14
from mi_nest.rig.sim.pty import PtyBridge

PULSES = 143360
INFO_LINE = b"0IN0E1140012320231701016800023000\r\n"


@pytest.fixture(autouse=True)
def fresh_simulation():
    sim.reset()
    yield
    sim.reset()


def open_mount(options="", **driver_options):
    url = "ell14sim://qwp2" + (f"?{options}" if options else "")
    driver = ELL14(url, **driver_options)
    return driver, sim.device(url)


def sent(device):
    return [message for _, message in device.log]


def counts(degrees, pulses=PULSES):
    return round(degrees * pulses / 360)


# Codec ----------------------------------------------------------------------

@pytest.mark.parametrize("command, expected", [
    (elliptec.get_info("0"), b"0in"),
    (elliptec.get_status("A"), b"Ags"),
    (elliptec.get_position("f"), b"Fgp"),
    (elliptec.home("0"), b"0ho0"),
    (elliptec.home("3", clockwise=False), b"3ho1"),
    (elliptec.move_absolute("0", 8960), b"0ma00002300"),          # 22.5 deg at 143360 counts per turn
    (elliptec.move_absolute("0", PULSES), b"0ma00023000"),
    (elliptec.move_absolute("0", -1), b"0maFFFFFFFF"),
    (elliptec.move_relative("2", -8960), b"2mrFFFFDD00"),
    (elliptec.move_absolute("0", 2**31 - 1), b"0ma7FFFFFFF"),
    (elliptec.move_absolute("0", -2**31), b"0ma80000000"),
])
def test_commands_are_byte_exact(command, expected):
    assert command == expected


@pytest.mark.parametrize("line, kind, value", [
    (b"0PO00002300\r\n", "PO", 8960),
    (b"0POFFFFFFFF\r\n", "PO", -1),
    (b"0PO80000000\r\n", "PO", -2**31),
    (b"0GS00\r\n", "GS", 0),
    (b"0GS09\r\n", "GS", 9),
    (b"AGS0D\r\n", "GS", 13),
])
def test_position_and_status_replies_decode(line, kind, value):
    reply = elliptec.decode_reply(line)
    assert (reply.kind, reply.value) == (kind, value)
    assert elliptec.encode_reply(reply) == line


def test_info_reply_decodes_every_field():
    reply = elliptec.decode_reply(INFO_LINE)
    assert reply.address == "0" and reply.kind == "IN"
    assert reply.value == elliptec.Info(ell_type=0x0E, serial_number="11400123", year=2023, firmware="17",
                                        hardware=0x01, travel=360, pulses_per_unit=143360)
    assert not reply.value.imperial_thread and reply.value.hardware_revision == 1
    imperial = elliptec.decode_reply(INFO_LINE.replace(b"1701", b"1781")).value
    assert imperial.imperial_thread and imperial.hardware_revision == 1
    assert elliptec.encode_reply(reply) == INFO_LINE


def test_status_names_cover_the_manual_codes():
    assert [elliptec.status_name(code) for code in (0, 2, 9, 13)] == [
        "ok", "mechanical time out", "busy", "over current error"]
    assert all(code in elliptec.STATUS_NAMES for code in range(14))
    assert elliptec.decode_reply(b"0GS02\r\n").status_name == "mechanical time out"
    assert "unknown" in elliptec.status_name(0x2A)


@pytest.mark.parametrize("line", [
    b"0PO00002300",             # no CR LF
    b"0PO00002300\n",           # LF only
    b"0PO00002300\r",           # CR only
    b"GPO00002300\r\n",         # address is not a hex digit
    b"0XX00002300\r\n",         # unknown reply
    b"0po00002300\r\n",         # replies are upper case
    b"0PO0000230\r\n",          # one digit lost
    b"0PO000023000\r\n",        # one digit too many
    b"0PO0000230G\r\n",         # not hex
    b"0PO0000230a\r\n",         # lower case hex
    b"0GS9\r\n",
    b"0IN0E114001232023170101680002300\r\n",
    b"0IN0E11400123YEAR1701016800023000\r\n",
    b"0PO\xff0002300\r\n",
    b"\r\n",
])
def test_malformed_replies_raise_value_error(line):
    with pytest.raises(ValueError):
        elliptec.decode_reply(line)


@pytest.mark.parametrize("address", ["G", "", "00", "-", 0, None])
def test_bad_addresses_are_rejected(address):
    with pytest.raises(ValueError, match="address"):
        elliptec.get_status(address)


@pytest.mark.parametrize("value", [2**31, -2**31 - 1, 10**12])
def test_positions_outside_32_bits_are_rejected(value):
    with pytest.raises(ValueError, match="32-bit"):
        elliptec.move_absolute("0", value)


def test_counts_round_trip_over_the_whole_signed_range():
    rng = np.random.default_rng(14)
    values = [int(v) for v in rng.integers(-2**31, 2**31, size=2000)]
    values += [0, 1, -1, 2**31 - 1, -2**31, PULSES, -PULSES]
    for value in values:
        text = elliptec.encode_counts(value)
        assert len(text) == 8 and text == text.upper()
        assert elliptec.decode_counts(text) == value
        assert int(text, 16) == value % 2**32


def test_commands_and_replies_round_trip():
    rng = np.random.default_rng(7)
    for value in (int(v) for v in rng.integers(-2**31, 2**31, size=500)):
        address = elliptec.ADDRESSES[value % 16]
        for encode, name in ((elliptec.move_absolute, "ma"), (elliptec.move_relative, "mr")):
            assert elliptec.decode_command(encode(address, value)) == elliptec.Command(address, name, value)
        reply = elliptec.Reply(address, "PO", value)
        assert elliptec.decode_reply(elliptec.encode_reply(reply)) == reply
    for code in range(256):
        reply = elliptec.Reply("5", "GS", code)
        assert elliptec.decode_reply(elliptec.encode_reply(reply)) == reply
    for clockwise in (True, False):
        assert elliptec.decode_command(elliptec.home("1", clockwise)).value == (0 if clockwise else 1)
    assert elliptec.decode_command(b"Cgp") == elliptec.Command("C", "gp")


@pytest.mark.parametrize("message", [b"0", b"0zz", b"0ma0000230", b"0ma0000230G", b"0ho2", b"0gs00", b"Xgs"])
def test_malformed_commands_raise_value_error(message):
    with pytest.raises(ValueError):
        elliptec.decode_command(message)


# Simulated mount, through its raw byte stream --------------------------------

def raw_port(options=""):
    return serial.serial_for_url("ell14sim://raw" + (f"?{options}" if options else ""), timeout=0.05)


def test_simulator_answers_identification_and_status():
    port = raw_port()
    port.write(b"0in")
    assert port.read_until(b"\n") == INFO_LINE
    port.write(b"0gs\r\n0gp")        # a host's CR LF between commands is ignored
    assert port.read(100) == b"0GS00\r\n0PO00000000\r\n"


def test_simulator_answers_a_move_only_when_it_has_finished():
    port = raw_port("seconds_per_turn=2")
    device = sim.device("ell14sim://raw")
    port.write(b"0ma00011800")                                    # half a turn: 1 s
    assert port.read(100) == b""
    port.write(b"0gs")
    assert port.read(100) == b"0GS09\r\n"
    port.write(b"0ma00000000")                                    # refused while moving
    assert port.read(100) == b"0GS09\r\n"
    port.write(b"0gp")
    moving = elliptec.decode_reply(port.read_until(b"\n")).value
    assert 0 < moving < 0x11800 and moving == device.current_position()
    sim.CLOCK.sleep(1.0 - sim.CLOCK.now())
    assert port.read(100) == b"0PO00011800\r\n"
    assert not device.moving and device.position == 0x11800


def test_simulator_answers_a_finished_move_before_the_next_command():
    port = raw_port()
    port.write(b"0ma00002300")
    sim.CLOCK.sleep(1.0)                                          # the move ended, nobody read since
    port.write(b"0gs")
    assert port.read(100) == b"0PO00002300\r\n0GS00\r\n"


def test_simulator_rejects_bad_commands_and_ignores_other_addresses():
    port = raw_port("address=3")
    port.write(b"0gs")
    assert port.read(100) == b""
    port.write(b"3zz")
    assert port.read(100) == b"3GS03\r\n"
    port.write(b"3ma00023000")                                    # one full turn is off the revolution
    assert port.read(100) == b"3GS04\r\n"
    port.write(b"3maFFFFFFFF")
    assert port.read(100) == b"3GS04\r\n"
    port.write(b"3ma0000")                                        # incomplete: dropped after the gap
    sim.CLOCK.sleep(2 * MESSAGE_GAP)
    assert port.read(100) == b"3GS01\r\n"
    port.write(b"5ma0000")                                        # another module's: not ours to answer
    sim.CLOCK.sleep(2 * MESSAGE_GAP)
    assert port.read(100) == b""
    port.write(b"3gs")
    assert port.read(100) == b"3GS00\r\n"


def test_relative_moves_cross_zero_and_report_one_revolution():
    port = raw_port()
    port.write(b"0mrFFFFDD00")                                    # -22.5 deg from 0
    sim.CLOCK.sleep(1.0)
    assert elliptec.decode_reply(port.read_until(b"\n")).value == PULSES - 8960


# Driver against the simulator -------------------------------------------------

def test_driver_identifies_the_mount_from_its_in_reply():
    driver, device = open_mount("pulses=136533")
    assert driver.info.ell_type == elliptec.ELL14_TYPE and driver.info.serial_number == "11400123"
    assert driver.pulses_per_revolution == 136533
    assert driver.move_to(90) == pytest.approx(90, abs=1 / driver.counts_per_degree)
    assert sent(device)[0] == b"0in" and sent(device)[-2] == elliptec.move_absolute("0", round(136533 / 4))


def test_driver_refuses_a_module_that_is_not_an_ell14():
    with pytest.raises(RigError, match="ELL18, not an ELL14"):
        open_mount("type=12")


def test_home_goes_to_zero_in_the_asked_direction():
    driver, device = open_mount()
    driver.move_to(100)
    assert driver.home() == 0
    assert sent(device)[-2:] == [b"0ho0", b"0gp"]
    driver.move_to(100)
    started = sim.CLOCK.now()
    assert driver.home(clockwise=False) == 0
    assert sent(device)[-2] == b"0ho1"
    assert sim.CLOCK.now() - started == pytest.approx(100 / 360 * 1.5, abs=0.1)    # the short way back


@pytest.mark.parametrize("commanded, expected", [
    (90, 90), (22.5, 22.5), (-90, 270), (-0.5, 359.5), (370, 10), (360, 0), (720.25, 0.25), (359.999999, 0),
])
def test_moves_wrap_to_one_turn(commanded, expected):
    driver, device = open_mount()
    measured = driver.move_to(commanded)
    assert measured == pytest.approx(expected, abs=0.5 / driver.counts_per_degree)
    assert device.position == counts(expected) % PULSES
    assert driver.position() == measured


def test_move_returns_the_measured_angle_not_the_commanded_one():
    driver, device = open_mount()
    device.inject("position_offset", counts=5)                    # within the tolerance: accepted as is
    measured = driver.move_to(45)
    assert measured == (counts(45) + 5) / driver.counts_per_degree
    assert measured != 45
    assert sent(device).count(elliptec.move_absolute("0", counts(45))) == 1


def test_moves_take_their_time_on_the_simulated_clock_only():
    driver, device = open_mount("seconds_per_turn=2")
    wall, started = time.monotonic(), sim.CLOCK.now()
    driver.move_to(180)
    assert 1.0 <= sim.CLOCK.now() - started <= 1.1
    started = sim.CLOCK.now()
    driver.move_to(90)
    assert 0.5 <= sim.CLOCK.now() - started <= 0.6
    assert time.monotonic() - wall < 0.5


def test_bad_input_is_rejected_before_anything_is_sent():
    with pytest.raises(ValueError, match="address"):
        ELL14("ell14sim://qwp2", address="G")
    with pytest.raises(ValueError, match="retries"):
        ELL14("ell14sim://qwp2", retries=-1)
    driver, device = open_mount()
    before = len(device.log)
    for angle in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError, match="finite"):
            driver.move_to(angle)
    assert len(device.log) == before


def test_closed_driver_reports_instead_of_crashing():
    with open_mount()[0] as driver:
        driver.position()
    with pytest.raises(CommunicationError, match="closed"):
        driver.position()


# Faults -------------------------------------------------------------------

def test_lost_query_reply_is_retried():
    driver, device = open_mount()
    driver.move_to(30)
    device.inject("no_reply")
    assert driver.position() == pytest.approx(30, abs=0.01)
    assert sent(device)[-2:] == [b"0gp", b"0gp"]


def test_query_that_never_gets_an_answer_raises_communication_error():
    driver, device = open_mount(retries=2)
    device.inject("no_reply", count=3)
    with pytest.raises(CommunicationError, match="no reply") as error:
        driver.position()
    assert error.value.code is None
    assert sent(device)[-3:] == [b"0gp"] * 3
    assert driver.position() == 0                                  # and the next one works


def test_swallowed_move_is_repeated_only_after_reading_the_position_back():
    driver, device = open_mount()
    device.inject("no_reply")
    assert driver.move_to(60) == pytest.approx(60, abs=0.01)
    move = elliptec.move_absolute("0", counts(60))
    assert sent(device)[-5:] == [move, b"0gs", b"0gp", move, b"0gp"]


def test_busy_reply_to_a_move_waits_then_reads_back_before_moving_again():
    driver, device = open_mount()
    device.inject("busy")
    assert driver.move_to(120) == pytest.approx(120, abs=0.01)
    move = elliptec.move_absolute("0", counts(120))
    assert sent(device)[-5:] == [move, b"0gs", b"0gp", move, b"0gp"]


def test_busy_query_waits_until_the_mount_is_free():
    driver, device = open_mount()
    device.inject("busy", count=3)
    assert driver.position() == 0
    assert sent(device)[-5:] == [b"0gp", b"0gs", b"0gs", b"0gs", b"0gp"]


def test_mount_that_stays_busy_raises_device_busy_with_its_code():
    driver, device = open_mount(busy_timeout=1.0)
    device.inject("busy", count=100)
    started = sim.CLOCK.now()
    with pytest.raises(DeviceBusy, match="busy") as error:
        driver.move_to(10)
    assert error.value.code == elliptec.BUSY
    assert 1.0 <= sim.CLOCK.now() - started < 1.5
    assert sent(device).count(elliptec.move_absolute("0", counts(10))) == 1


def test_mechanical_timeout_is_reported_with_the_device_code_and_not_retried():
    driver, device = open_mount()
    device.inject("mechanical_timeout")
    with pytest.raises(MotionError, match="mechanical time out") as error:
        driver.move_to(200)
    assert error.value.code == elliptec.MECHANICAL_TIMEOUT
    assert 0 < device.position < counts(200)                      # it stopped partway
    assert sent(device).count(elliptec.move_absolute("0", counts(200))) == 1
    assert driver.move_to(200) == pytest.approx(200, abs=0.01)     # and can move again


@pytest.mark.parametrize("index", [5, -1, 0])                      # a data digit, the LF, the address
def test_reply_with_a_dropped_byte_is_detected_and_the_query_retried(index):
    driver, device = open_mount()
    driver.move_to(75)
    device.inject("dropped_byte", index=index)
    assert driver.position() == pytest.approx(75, abs=0.01)
    assert sent(device)[-2:] == [b"0gp", b"0gp"]


def test_garbled_replies_that_persist_raise_communication_error_and_leave_the_line_clean():
    driver, device = open_mount(retries=1)
    device.inject("dropped_byte", count=2)
    with pytest.raises(CommunicationError, match="garbled"):
        driver.position()
    assert device.output == b""
    assert driver.position() == 0


def test_garbled_move_reply_is_checked_by_reading_back_not_by_moving_again():
    driver, device = open_mount()
    device.inject("dropped_byte")
    assert driver.move_to(250) == pytest.approx(250, abs=0.01)
    move = elliptec.move_absolute("0", counts(250))
    assert sent(device)[-3:] == [move, b"0gs", b"0gp"]
    assert sent(device).count(move) == 1


def test_move_reply_arriving_while_status_is_polled_is_not_an_error():
    driver, device = open_mount("seconds_per_turn=2", move_timeout=0.2, retries=0)
    assert driver.move_to(180) == pytest.approx(180, abs=0.01)    # PO came after the wait, during gs polling
    assert sent(device).count(b"0gs") > 1 and sent(device)[-1] == b"0gp"


def test_stale_reply_on_the_line_is_not_taken_as_the_answer():
    driver, device = open_mount(retries=0)
    driver.move_to(30)
    device.output += elliptec.encode_reply(elliptec.Reply("0", "PO", 12345))     # a late reply to an old command
    assert driver.position() == pytest.approx(30, abs=0.01)


def test_position_off_target_is_moved_once_more():
    driver, device = open_mount()
    device.inject("position_offset", counts=500)
    assert driver.move_to(45) == pytest.approx(45, abs=0.01)
    assert sent(device).count(elliptec.move_absolute("0", counts(45))) == 2


def test_position_off_target_twice_raises_motion_error():
    driver, device = open_mount(tolerance_counts=3)
    device.inject("position_offset", count=2, counts=-4)
    with pytest.raises(MotionError, match="-4 counts from the target, twice") as error:
        driver.move_to(45)
    assert error.value.code is None
    assert device.position == counts(45) - 4


def test_disconnect_mid_move_then_reopen_finds_the_mount_partway():
    driver, device = open_mount()
    driver.move_to(10)
    device.inject("disconnect_mid_move")
    with pytest.raises(CommunicationError, match="port lost"):
        driver.move_to(190)
    with pytest.raises(CommunicationError, match="cannot open"):
        driver.reopen()
    device.disconnected = False
    driver.reopen()
    assert 10 < driver.position() < 190
    assert driver.position() == pytest.approx(100, abs=0.01)
    assert driver.move_to(190) == pytest.approx(190, abs=0.01)


# Through a real pseudo-terminal ---------------------------------------------------

def test_driver_works_through_a_kernel_pty():
    device = SimulatedELL14("pty", {"address": "2"})
    with PtyBridge(device, speedup=20) as path:
        with serial.Serial(path, 9600, timeout=0.5) as raw:
            raw.write(b"2gs")
            assert raw.read_until(b"\n") == b"2GS00\r\n"
        with ELL14(path, address="2", port_factory=serial.Serial) as driver:
            assert driver.pulses_per_revolution == PULSES
            assert driver.move_to(-45) == pytest.approx(315, abs=0.01)
            assert device.position == counts(315)
            device.inject("dropped_byte")
            assert driver.position() == pytest.approx(315, abs=0.01)


def test_a_port_that_echoes_is_no_mount():
    """``loop://`` sends every command straight back: the driver must refuse it quickly, not hang."""
    with pytest.raises(CommunicationError):
        ELL14("loop://", timeout=0.05, retries=1)
