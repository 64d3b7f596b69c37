"""The APT codec byte for byte, the simulated KST/BSC controller with its HDR50, and the HDR50 driver against it:
probe and fallback, homing and moves on the simulated clock, every injectable fault, and a real pseudo-terminal."""
import time

import pytest
import serial

from mi_nest.rig import apt, sim
from mi_nest.rig.errors import CommunicationError, DeviceBusy, MotionError
from mi_nest.rig.hdr50 import COUNTS_PER_REVOLUTION, HDR50
from mi_nest.rig.sim.protocol_aptsim import SimulatedStepperController
from mi_nest.rig.sim.pty import PtyBridge


@pytest.fixture(autouse=True)
def fresh_simulation():
    sim.reset()
    yield
    sim.reset()


def sent(device, message_type):
    """Messages of ``message_type`` the simulated controller received, in order."""
    return [m for m in (apt.decode(frame) for _, frame in device.log) if isinstance(m, message_type)]


def near(degrees):
    """A position the stage can reach: within one microstep of ``degrees``."""
    return pytest.approx(degrees, abs=360 / COUNTS_PER_REVOLUTION)


def raw_port(url):
    return serial.serial_for_url(url, timeout=0.1)


# --- codec ------------------------------------------------------------------------------------------
FIXTURES = [
    # thorlabs-apt-protocol README: mot_move_home(source=1, dest=0x50, chan_ident=1)
    (apt.MoveHome(1, dest=0x50), "43 04 01 00 50 01"),
    # thorlabs-apt-protocol README: mot_move_absolute(..., position=2048)
    (apt.MoveAbsolute(1, 2048, dest=0x50), "53 04 06 00 d0 01 01 00 00 08 00 00"),
    # 90 degrees on the HDR50 = 6,758,400 microsteps = 0x00672000
    (apt.MoveAbsolute(1, 6_758_400, dest=0x50), "53 04 06 00 d0 01 01 00 00 20 67 00"),
    (apt.MoveRelative(1, -75_093, dest=0x21), "48 04 06 00 a1 01 01 00 ab da fe ff"),
    # pnpq's fixture for MGMSG_MOT_MOVE_COMPLETED from the protocol document
    (apt.MoveCompleted(1, 0x01A0AA68, 0, 0x80000030, dest=apt.HOST, source=0x50),
     "64 04 0e 00 81 50 01 00 68 aa a0 01 00 00 00 00 30 00 00 80"),
    (apt.ReqInfo(dest=0x50), "05 00 00 00 50 01"),
    (apt.NoFlashProgramming(dest=0x11), "18 00 00 00 11 01"),
    (apt.StopUpdateMessages(dest=0x50), "12 00 00 00 50 01"),
    (apt.SetChannelEnableState(1, apt.ENABLE, dest=0x50), "10 02 01 01 50 01"),
    (apt.SetChannelEnableState(1, apt.DISABLE, dest=0x21), "10 02 01 02 21 01"),
    (apt.ReqPositionCounter(1, dest=0x50), "11 04 01 00 50 01"),
    (apt.GetPositionCounter(1, -1, dest=apt.HOST, source=0x50), "12 04 06 00 81 50 01 00 ff ff ff ff"),
    (apt.ReqStatusBits(1, dest=0x50), "29 04 01 00 50 01"),
    (apt.GetStatusBits(1, apt.ENABLED | apt.HOMED, dest=apt.HOST, source=0x50), "2a 04 06 00 81 50 01 00 00 04 00 80"),
    (apt.MoveHomed(1, dest=apt.HOST, source=0x50), "44 04 01 00 01 50"),
    (apt.MoveStop(1, apt.STOP_IMMEDIATE, dest=0x50), "65 04 01 01 50 01"),
]


@pytest.mark.parametrize("message, wire", FIXTURES, ids=[type(m).__name__ for m, _ in FIXTURES])
def test_messages_encode_to_pinned_bytes_and_back(message, wire):
    assert apt.encode(message) == bytes.fromhex(wire)
    assert apt.decode(bytes.fromhex(wire)) == message


def test_get_info_layout_matches_the_84_byte_block():
    info = apt.GetInfo(26000201, "KST201", 16, 0x03000B, "HDR50", 3, 1, 1, dest=apt.HOST, source=0x50)
    frame = apt.encode(info)
    assert frame[:6] == bytes.fromhex("06 00 54 00 81 50")           # long form, 84 data bytes
    data = frame[6:]
    assert data[0:4] == (26000201).to_bytes(4, "little")
    assert data[4:12] == b"KST201\0\0"
    assert data[12:14] == b"\x10\x00"
    assert data[14:18] == bytes([11, 0, 3, 0])                        # minor, interim, major (pylablib)
    assert data[18:23] == b"HDR50" and set(data[23:78]) == {0}
    assert data[78:84] == bytes([3, 0, 1, 0, 1, 0])
    assert apt.decode(frame) == info and info.firmware_version == "3.0.11"


def test_stop_messages_and_rich_response_round_trip():
    for message in (apt.MoveStopped(1, -5, 0, apt.ENABLED, dest=apt.HOST, source=0x21),
                    apt.HwRichResponse(0x0453, 42, "move refused", dest=apt.HOST, source=0x50),
                    apt.HwResponse(dest=apt.HOST, source=0x50)):
        assert apt.decode(apt.encode(message)) == message


def test_headers_build_and_parse_both_forms():
    short = apt.Header(0x0443, 0x50, apt.HOST, False, 1, 0)
    long = apt.Header(0x0453, 0x50, apt.HOST, True, length=6)
    assert short.pack() == bytes.fromhex("43 04 01 00 50 01")
    assert long.pack() == bytes.fromhex("53 04 06 00 d0 01")
    assert apt.parse_header(short.pack()) == short and apt.parse_header(long.pack()) == long


@pytest.mark.parametrize("frame, complaint", [
    ("53 04 06 00 d0", "truncated APT header"),
    ("99 09 00 00 50 01", "unknown APT message id 0x0999"),
    ("53 04 01 00 50 01", "must be long form"),
    ("43 04 02 00 d0 01 01 00", "must be short form"),
    ("53 04 06 00 d0 01 01 00 00 08 00", "carries 6 data bytes"),            # one byte short
    ("53 04 04 00 d0 01 01 00 00 08", "carries 6 data bytes"),               # header lies about the length
    ("43 04 01 00 50 01 00", "6-byte message"),
])
def test_malformed_frames_raise_clear_errors(frame, complaint):
    with pytest.raises(ValueError, match=complaint):
        apt.decode(bytes.fromhex(frame))


@pytest.mark.parametrize("message", [
    apt.MoveAbsolute(1, 2**31, dest=0x50),                  # int32 overflow
    apt.MoveHome(300, dest=0x50),                           # a parameter byte
    apt.MoveHome(1, dest=0xD0),                             # collides with the long-form flag
    apt.GetInfo(1, "KST201-TOO-LONG", 16, 0, "", 0, 0, 1, dest=1, source=0x50),
])
def test_values_that_do_not_fit_are_refused(message):
    with pytest.raises(ValueError, match="cannot encode"):
        apt.encode(message)


def test_framer_reassembles_split_and_concatenated_streams():
    stream = b"".join(apt.encode(m) for m, _ in FIXTURES)
    framer = apt.Framer()
    frames = []
    for i in range(len(stream)):                            # one byte at a time
        framer.feed(stream[i:i + 1])
        frames += framer.frames()
    assert [apt.decode(f) for f in frames] == [m for m, _ in FIXTURES]
    framer.feed(stream + stream[:9])                       # all at once, then one short and half a long one
    assert len(list(framer.frames())) == len(FIXTURES) + 1 and framer.pending == 3
    framer.feed(stream[9:18])
    assert [apt.decode(f) for f in framer.frames()] == [FIXTURES[1][0]]
    assert framer.pending == 0


def test_framer_drops_a_stream_that_lost_step():
    framer = apt.Framer()
    framer.feed(apt.encode(apt.ReqInfo(dest=0x50)) + bytes.fromhex("53 04 00 10 d0 01 00 00"))   # 4096 bytes announced
    frames = framer.frames()
    assert apt.decode(next(frames)) == apt.ReqInfo(dest=0x50)
    with pytest.raises(ValueError, match="announces 4096 data bytes"):
        next(frames)
    assert framer.pending == 0


def test_status_bits_are_named():
    assert apt.describe_status(apt.MOVING_CW | apt.HOMED | apt.ENABLED) == "moving CW, homed, enabled"
    assert apt.describe_status(0) == "idle, not homed, disabled"


# --- simulated controller ---------------------------------------------------------------------------
def test_simulator_moves_on_the_simulated_clock_and_reports_when_done():
    port = raw_port("aptsim://raw?speed=20")
    device = sim.device("aptsim://raw")
    port.write(apt.encode(apt.MoveAbsolute(1, 6_758_400, dest=0x50)))
    assert device.motion is None, "a disabled channel must ignore moves"
    port.write(apt.encode(apt.SetChannelEnableState(1, apt.ENABLE, dest=0x50)))
    port.write(apt.encode(apt.MoveAbsolute(1, 6_758_400, dest=0x50)))       # 90 degrees at 20 deg/s: 4.5 s
    assert device.status() & apt.MOVING_CW and not device.status() & apt.MOVING_CCW
    sim.CLOCK.sleep(4.4)
    assert port.in_waiting == 0 and 6_600_000 < device.position() < 6_758_400
    sim.CLOCK.sleep(0.2)
    done = apt.decode(port.read(20))
    assert done == apt.MoveCompleted(1, 6_758_400, 0, apt.ENABLED | apt.MOTOR_CONNECTED, dest=apt.HOST, source=0x50)
    port.write(apt.encode(apt.MoveRelative(1, -6_758_400 * 2, dest=0x50)))
    assert device.status() & apt.MOVING_CCW
    port.write(apt.encode(apt.MoveAbsolute(1, 0, dest=0x50)))               # ignored: a motion is running
    sim.CLOCK.sleep(9.1)
    assert apt.decode(port.read(20)).position == -6_758_400
    port.write(apt.encode(apt.ReqInfo(dest=0x51)))                          # nobody there
    port.write(apt.encode(apt.GetInfo(0, "", 0, 0, "", 0, 0, 0, dest=0x50)))    # only a host takes this
    assert apt.decode(port.read(6)) == apt.HwResponse(dest=apt.HOST, source=0x50) and port.read(1) == b""


def test_simulator_homes_ccw_to_the_switch():
    port = raw_port("aptsim://raw?angle=30")
    device = sim.device("aptsim://raw")
    port.write(apt.encode(apt.SetChannelEnableState(1, apt.ENABLE, dest=0x50)))
    port.write(apt.encode(apt.MoveHome(1, dest=0x50)))
    assert device.status() & (apt.HOMING | apt.MOVING_CCW) == apt.HOMING | apt.MOVING_CCW
    sim.CLOCK.sleep(3.01)                                                    # 30 degrees at 10 deg/s
    assert apt.decode(port.read(6)) == apt.MoveHomed(1, dest=apt.HOST, source=0x50)
    assert device.counter == 0 and device.status() & apt.HOMED


def test_unknown_model_is_refused():
    with pytest.raises(ValueError, match="model must be one of"):
        raw_port("aptsim://raw?model=KDC101")


# --- driver -----------------------------------------------------------------------------------------
def test_open_probes_identifies_and_enables():
    with HDR50("aptsim://az") as stage:
        device = sim.device("aptsim://az")
        assert stage.address == apt.USB_UNIT and stage.info.model == "KST201"
        assert stage.name == "HDR50 on KST201 #26000201 (aptsim://az)"
        assert device.enabled and stage.status() & apt.ENABLED
        assert sent(device, apt.NoFlashProgramming) and sent(device, apt.StopUpdateMessages)
        assert [m.dest for m in sent(device, apt.ReqInfo)] == [apt.USB_UNIT]


def test_probe_falls_back_to_a_rack_and_drives_the_bay():
    with HDR50("aptsim://el?address=0x11&model=BSC201") as stage:
        device = sim.device("aptsim://el")
        assert stage.address == apt.RACK and stage.info.model == "BSC201"
        assert [m.dest for m in sent(device, apt.ReqInfo)] == [apt.USB_UNIT, apt.RACK]
        assert stage.move_to(45) == 45.0
        assert {m.dest for m in sent(device, apt.MoveAbsolute)} == {apt.bay(1)}


def test_no_controller_at_all_is_reported():
    with pytest.raises(CommunicationError, match="no APT controller answered") as caught:
        HDR50("aptsim://nobody?address=0x33", retries=1)
    assert "aptsim://nobody" in str(caught.value)
    assert len(sent(sim.device("aptsim://nobody"), apt.ReqInfo)) == 4      # 2 rounds x (0x50, 0x11)


def test_home_and_moves_return_measured_positions_in_simulated_time():
    wall = time.monotonic()
    with HDR50("aptsim://az?angle=37.5") as stage:
        device = sim.device("aptsim://az")
        t0 = sim.CLOCK.now()
        assert stage.home() == 0.0 and stage.status() & apt.HOMED
        assert 3.75 <= sim.CLOCK.now() - t0 < 4.0
        t0 = sim.CLOCK.now()
        assert stage.move_to(90) == 90.0
        assert 9.0 <= sim.CLOCK.now() - t0 < 9.3
        assert device.counter == 6_758_400 == sent(device, apt.MoveAbsolute)[-1].position
        assert stage.move_to(-12.3456) == pytest.approx(-12.3456, abs=360 / COUNTS_PER_REVOLUTION)
        assert stage.position() == device.counter * 360 / COUNTS_PER_REVOLUTION
    assert time.monotonic() - wall < 2.0


def test_speed_is_a_url_option():
    with HDR50("aptsim://fast?speed=30") as stage:
        t0 = sim.CLOCK.now()
        stage.move_to(90)
        assert 3.0 <= sim.CLOCK.now() - t0 < 3.3


def test_a_channel_disabled_behind_the_drivers_back_is_enabled_again():
    with HDR50("aptsim://az") as stage:
        sim.device("aptsim://az").receive(apt.encode(apt.SetChannelEnableState(1, apt.DISABLE, dest=0x50)))
        assert not stage.status() & apt.ENABLED
        assert stage.move_to(10) == near(10.0)


def test_adapter_without_rts_warns_and_works():
    with pytest.warns(RuntimeWarning, match="cannot set RTS"):
        stage = HDR50("aptsim://az?no_rts=1")
    with stage:
        assert stage.move_to(5) == near(5.0)


def test_port_that_cannot_open_is_a_communication_error():
    def refuse(url, **settings):
        raise serial.SerialException(f"could not open port {url}")
    with pytest.raises(CommunicationError, match="cannot open the port") as caught:
        HDR50("/dev/ttyUSB9", port_factory=refuse)
    assert caught.value.device == "HDR50 at /dev/ttyUSB9"


# --- faults -----------------------------------------------------------------------------------------
def test_lost_request_is_retried():
    with HDR50("aptsim://az") as stage:
        device = sim.device("aptsim://az")
        stage.move_to(30)
        before = len(sent(device, apt.ReqPositionCounter))
        device.inject("no_reply")
        assert stage.position() == 30.0
        assert len(sent(device, apt.ReqPositionCounter)) - before == 2


def test_silence_beyond_the_retries_names_the_device():
    with HDR50("aptsim://az", retries=2) as stage:
        sim.device("aptsim://az").inject("no_reply", count=3)
        with pytest.raises(CommunicationError, match="no GetPositionCounter reply .* after 3 attempts") as caught:
            stage.position()
        assert caught.value.device.startswith("HDR50 on KST201")


def test_lost_move_is_commanded_again_after_reading_back():
    with HDR50("aptsim://az") as stage:
        device = sim.device("aptsim://az")
        device.inject("no_reply", message=apt.MoveAbsolute.ID)
        assert stage.move_to(20) == near(20.0)
        assert [m.position for m in sent(device, apt.MoveAbsolute)] == [1_501_867, 1_501_867]


def test_busy_controller_ignores_the_move_and_the_driver_moves_again():
    with HDR50("aptsim://az") as stage:
        device = sim.device("aptsim://az")
        device.inject("busy", seconds=0.5)
        assert stage.move_to(-20) == near(-20.0)
        assert len(sent(device, apt.MoveAbsolute)) == 2


def test_busy_twice_is_a_motion_error_with_the_status_bits():
    with HDR50("aptsim://az") as stage:
        sim.device("aptsim://az").inject("busy", count=2, seconds=0.5)
        with pytest.raises(MotionError, match="position read back") as caught:
            stage.move_to(-20)
        assert caught.value.code & apt.ENABLED and not caught.value.code & apt.MOTION


def test_motion_started_elsewhere_that_outlasts_the_wait_is_device_busy():
    with HDR50("aptsim://az", busy_timeout=1.0) as stage:
        device = sim.device("aptsim://az")
        device.receive(apt.encode(apt.MoveAbsolute(1, 27_033_600, dest=0x50)))     # a 36 s turn from the panel
        with pytest.raises(DeviceBusy, match="still moving after 1.0 s") as caught:
            stage.move_to(10)
        assert caught.value.code & apt.MOVING_CW
        assert len(sent(device, apt.MoveAbsolute)) == 1


def test_stall_is_stopped_and_reported_then_the_stage_works_again():
    with HDR50("aptsim://az", stall_timeout=1.0) as stage:
        device = sim.device("aptsim://az")
        device.inject("mechanical_timeout")
        with pytest.raises(MotionError, match="stalled at 1501867 microsteps") as caught:
            stage.move_to(60)                                                        # stalls at 20 degrees
        assert caught.value.code == apt.ENABLED | apt.MOTOR_CONNECTED             # stopped, so idle again
        assert sent(device, apt.MoveStop) and device.motion is None
        assert stage.move_to(60) == 60.0


def test_a_motion_that_runs_past_its_time_limit_is_stopped():
    with HDR50("aptsim://az?speed=0.5", motion_timeout=10.0) as stage:          # 60 degrees would take 120 s
        device = sim.device("aptsim://az?speed=0.5")
        start = stage.clock.now()
        with pytest.raises(MotionError, match="still moving"):
            stage.move_to(60)
        assert 10.0 <= stage.clock.now() - start < 12.0
        assert sent(device, apt.MoveStop) and device.motion is None


def test_dropped_byte_in_a_reply_is_resynchronised():
    with HDR50("aptsim://az") as stage:
        device = sim.device("aptsim://az")
        stage.move_to(15)
        before = len(sent(device, apt.ReqPositionCounter))
        device.inject("dropped_byte")
        assert stage.position() == 15.0
        assert len(sent(device, apt.ReqPositionCounter)) - before == 2


def test_dropped_byte_in_the_completion_message_does_not_fool_the_move():
    with HDR50("aptsim://az", poll_interval=20.0) as stage:     # so the completion comes before any status poll
        device = sim.device("aptsim://az")
        stage.move_to(5)
        device.inject("dropped_byte", message=apt.MoveCompleted.ID)
        assert stage.move_to(40) == near(40.0)
        assert len(sent(device, apt.MoveAbsolute)) == 2


def test_position_offset_is_corrected_once_and_then_reported():
    with HDR50("aptsim://az") as stage:
        device = sim.device("aptsim://az")
        device.inject("position_offset", counts=500)
        assert stage.move_to(10) == near(10.0) and device.counter == 750_933
        device.inject("position_offset", count=2, counts=-40)
        with pytest.raises(MotionError, match="read back 1501827 microsteps, commanded 1501867") as caught:
            stage.move_to(20)
        assert caught.value.code & apt.ENABLED


def test_offset_within_tolerance_is_accepted():
    with HDR50("aptsim://az", tolerance=50) as stage:
        device = sim.device("aptsim://az")
        device.inject("position_offset", counts=-40)
        assert stage.move_to(20) == pytest.approx(20 - 40 * 360 / COUNTS_PER_REVOLUTION)
        assert len(sent(device, apt.MoveAbsolute)) == 1


def test_disconnect_mid_move_then_reopen_finds_the_stage():
    stage = HDR50("aptsim://az")
    device = sim.device("aptsim://az")
    stage.move_to(10)
    device.inject("disconnect_mid_move")
    with pytest.raises(CommunicationError, match="serial link lost"):
        stage.move_to(70)                                                           # 6 s; the link drops at 3 s
    stage.close()
    assert device.disconnected
    with pytest.raises(CommunicationError, match="cannot open"):
        HDR50("aptsim://az")
    sim.CLOCK.sleep(5)
    device.disconnected = False
    with HDR50("aptsim://az") as again:
        assert again.position() == near(70.0)                # the separately powered cube finished the move
        assert again.move_to(0) == 0.0


def test_error_report_from_the_controller_carries_its_code():
    with HDR50("aptsim://az") as stage:
        device = sim.device("aptsim://az")
        device.output += apt.encode(apt.HwRichResponse(0x0453, 42, "motor overheating", dest=apt.HOST, source=0x50))
        with pytest.raises(CommunicationError, match="motor overheating") as caught:
            stage.position()
        assert caught.value.code == 42


def test_garbage_on_the_line_is_skipped():
    with HDR50("aptsim://az") as stage:
        device = sim.device("aptsim://az")
        device.output += bytes.fromhex("99 09 00 00 01 50")       # a message id nobody knows
        device.output += bytes.fromhex("12 04 00 20 81 50")       # 8192 data bytes announced: out of step
        assert stage.position() == 0.0


# --- a real tty -------------------------------------------------------------------------------------
def test_driver_through_a_pseudo_terminal():
    device = SimulatedStepperController("pty", {"speed": "90", "angle": "20"})
    with PtyBridge(device, speedup=20) as path:
        with pytest.warns(RuntimeWarning, match="cannot set RTS"):            # a pty has no modem lines
            stage = HDR50(path, timeout=0.5, poll_interval=0.02, stall_timeout=1.0)
        with stage:
            assert stage.info.model == "KST201"
            assert stage.home() == 0.0
            assert stage.move_to(45) == 45.0
            assert stage.position() == 45.0
    assert device.counter == 3_379_200


def test_a_port_that_echoes_is_no_controller():
    """``loop://`` sends every request straight back (a HW_REQ_INFO is no HW_GET_INFO): refused, not hung."""
    with pytest.raises(CommunicationError):
        HDR50("loop://", timeout=0.05, retries=1)
