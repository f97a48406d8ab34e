"""The simulated rover over real pyserial connections to its ptys: commands, logs, timing, RTK, faults."""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable, Iterator

import numpy as np
import pymap3d
import pytest
import serial

from drivers.novatel import (
    BestPos,
    BestVel,
    BestXyz,
    Frame,
    FrameKind,
    Heading,
    MarkPos,
    MarkTime,
    PositionType,
    PsrDop,
    RawBody,
    Time,
    encode_ok,
    encode_prompt,
)
from sim_devices.gnss import RtkParams, SimBase, SimRover, SimTimeBase, SyncSchedule
from sim_devices.vehicle import GroundTruth, point_geodetic
from tests.sim_gnss.conftest import SPEED, PortReader
from vsccore.gpstime import NS_PER_S

LEVER_A = (0.6, 0.0, 1.0)
LEVER_B = (-0.98, 0.0, 1.0)
FAST_RTK = RtkParams(max_correction_age_s=2.5, float_hold_s=4.0, psrdiff_timeout_s=6.0, time_to_float_s=1.0,
                     time_to_fix_s=3.0)

Opener = Callable[..., PortReader]


@pytest.fixture
def make_rover(truth: GroundTruth, timebase: SimTimeBase) -> Iterator[Callable[..., SimRover]]:
    made: list[SimRover] = []
    clock = timebase.make_clock(speed=SPEED, lead_s=0.0)

    def make(**kw: object) -> SimRover:
        args: dict[str, object] = {"truth": truth, "lever_arm": LEVER_A, "timebase": timebase, "clock": clock}
        args.update(kw)
        rover = SimRover(str(args.pop("name", "rover_a")), **args)  # type: ignore[arg-type]
        rover.start()
        made.append(rover)
        return rover

    yield make
    for r in made:
        r.stop()


def _logs(frames: list[Frame], name: str) -> list[Frame]:
    return [f for f in frames if f.log is not None and f.log.name == name]


def _truth_at(truth: GroundTruth, tb: SimTimeBase, gps_ns: int, lever: tuple[float, float, float]
              ) -> tuple[float, float, float]:
    t = tb.truth_s(gps_ns)
    lat, lon, h = point_geodetic(truth, *lever)
    return (float(np.interp(t, truth.t, lat)), float(np.interp(t, truth.t, lon)), float(np.interp(t, truth.t, h)))


def _enu_error(body: BestPos | MarkPos, ref: tuple[float, float, float]) -> np.ndarray:
    e, n, u = pymap3d.geodetic2enu(body.lat_deg, body.lon_deg, body.hgt_m + body.undulation_m, *ref)
    return np.array([e, n, u], dtype=float)


# --- commands ------------------------------------------------------------------------------------


def test_commands_answered_like_an_oem7(make_rover: Callable[..., SimRover], open_port: Opener) -> None:
    rover = make_rover()
    port = open_port(rover.port_path, 460800)
    port.port.write(b"LOG BESTPOSA ONTIME 1\r\n")
    raw = b""
    while encode_prompt("COM1") not in raw:
        chunk = port.port.read(256)
        raw += chunk
        assert len(raw) < 4096
    assert raw.startswith(encode_ok() + encode_prompt("COM1"))  # exactly "<OK\r\n[COM1]"
    assert port.command("UNLOGALL").message.ok
    assert port.command("INTERFACEMODE COM2 RTCMV3 NONE OFF").message.ok
    assert port.command("SERIALCONFIG COM2 115200 N 8 1 N OFF").message.ok
    assert port.command("EVENTINCONTROL MARK1 EVENT POSITIVE 0 4").message.ok
    assert port.command("SAVECONFIG").message.ok
    bad = port.command("FOOBAR 1 2")
    assert not bad.message.ok and bad.message.text == "Invalid Message ID"
    assert port.command("LOG HEADINGA ONTIME 1").message.text == "Invalid Message. Field = 2"  # single antenna
    assert port.command("LOG BESTPOSB ONTIME 0.3").message.text == "Parameter 4 Out Of Range"
    assert port.command("UNLOG BESTVELB").message.text == "Message Not Found"
    prompts = [f for f in port.frames if f.kind is FrameKind.PROMPT]
    assert len(prompts) == len([f for f in port.frames if f.kind is FrameKind.RESPONSE])
    assert rover.errors_sent == 4


def test_logs_decode_and_match_truth(make_rover: Callable[..., SimRover], open_port: Opener, truth: GroundTruth,
                                     timebase: SimTimeBase) -> None:
    rover = make_rover()
    port = open_port(rover.port_path)
    for cmd in ("LOG BESTPOSB ONTIME 0.1", "LOG BESTVELA ONTIME 0.1", "LOG BESTXYZB ONTIME 0.5",
                "LOG PSRDOPA ONTIME 1", "LOG TIMEB ONTIME 1", "LOG BESTPOS ONTIME 0.5", "LOG RANGECMPB ONTIME 1",
                "LOG VERSIONA ONCE"):
        assert port.command(cmd).message.ok, cmd
    frames = port.until(lambda fs: len(_logs(fs, "TIME")) >= 2 and len(_logs(fs, "BESTVEL")) >= 10
                        and all(_logs(fs, n) for n in ("RANGECMP", "VERSION", "PSRDOP", "BESTXYZ")))
    # SINGLE (no corrections): errors within 5 σ of the reported sigmas, sigmas as configured.
    for f in _logs(frames, "BESTPOS"):
        body = f.log.body
        assert isinstance(body, BestPos) and body.pos_type is PositionType.SINGLE
        err = _enu_error(body, _truth_at(truth, timebase, f.log.header.gps_ns, LEVER_A))
        assert abs(err[0]) < 5 * body.lon_sigma_m and abs(err[1]) < 5 * body.lat_sigma_m
        assert abs(err[2]) < 5 * body.hgt_sigma_m
        assert body.num_soln_svs >= 6 and body.diff_age_s == 0.0
    assert {f.kind for f in _logs(frames, "BESTPOS")} == {FrameKind.NOVATEL_BINARY, FrameKind.NOVATEL_ABBREV}
    for f in _logs(frames, "BESTVEL"):
        body = f.log.body
        assert isinstance(body, BestVel)
        t = timebase.truth_s(f.log.header.gps_ns)
        ve, vn = (float(np.interp(t, truth.t, v)) for v in truth.point_velocity_enu(*LEVER_A[:2]))
        assert body.hor_spd_mps == pytest.approx(math.hypot(ve, vn), abs=0.3)
        track = math.degrees(math.atan2(ve, vn)) % 360
        assert abs((body.trk_gnd_deg - track + 180) % 360 - 180) < 2.0
    for f in _logs(frames, "BESTXYZ"):
        body = f.log.body
        assert isinstance(body, BestXyz)
        ref = pymap3d.geodetic2ecef(*_truth_at(truth, timebase, f.log.header.gps_ns, LEVER_A))
        assert math.dist((body.p_x_m, body.p_y_m, body.p_z_m), ref) < 15.0
    dop = _logs(frames, "PSRDOP")[0].log.body
    assert isinstance(dop, PsrDop) and 0.5 < dop.pdop < 4.0 and len(dop.prns) >= 6
    rng = _logs(frames, "RANGECMP")[0].log.body
    assert isinstance(rng, RawBody)
    count = int.from_bytes(rng.data[:4], "little")
    assert count >= 12 and len(rng.data) == 4 + 24 * count
    version = _logs(frames, "VERSION")
    assert len(version) == 1 and b"GPSCARD" in version[0].raw


def test_time_log_reports_leap_seconds(make_rover: Callable[..., SimRover], open_port: Opener) -> None:
    import datetime as dt

    rover = make_rover()
    port = open_port(rover.port_path)
    assert port.command("LOG TIMEA ONTIME 1").message.ok
    f = _logs(port.until(lambda fs: bool(_logs(fs, "TIME"))), "TIME")[0]
    body = f.log.body
    assert isinstance(body, Time) and body.utc_offset_s == -18.0 and body.leap_seconds == 18
    utc = dt.datetime(1980, 1, 6, tzinfo=dt.UTC) + dt.timedelta(seconds=f.log.header.gps_ns / NS_PER_S - 18)
    assert (body.utc_year, body.utc_month, body.utc_day, body.utc_hour, body.utc_min) == (
        utc.year, utc.month, utc.day, utc.hour, utc.minute
    )
    assert body.utc_ms == utc.second * 1000 + utc.microsecond // 1000


def test_log_rates_follow_the_gps_grid(make_rover: Callable[..., SimRover], open_port: Opener,
                                       timebase: SimTimeBase) -> None:
    rover = make_rover(output_latency_s=0.02, latency_jitter_s=0.002)
    port = open_port(rover.port_path, 460800)
    assert port.command("LOG BESTPOSB ONTIME 0.05").message.ok
    assert port.command("LOG BESTVELB ONTIME 0.2 0.1").message.ok
    arrivals: list[tuple[int, int]] = []

    def collect(fs: list[Frame]) -> bool:
        now = rover.clock.now_ns()
        for f in fs[len(collect.seen):]:  # type: ignore[attr-defined]
            if f.log is not None and f.log.name == "BESTPOS":
                arrivals.append((f.log.header.gps_ns, now))
        collect.seen = list(fs)  # type: ignore[attr-defined]
        return len(arrivals) >= 40

    collect.seen = []  # type: ignore[attr-defined]
    port.until(collect)
    times = [a[0] for a in arrivals]
    assert all(t % 50_000_000 == 0 for t in times)  # on the 20 Hz grid of GPS time
    assert np.all(np.diff(times) == 50_000_000)  # none missing, none doubled
    vel = [f.log.header.gps_ns for f in _logs(port.frames, "BESTVEL")]
    assert vel and all((t - 100_000_000) % 200_000_000 == 0 for t in vel)  # period 0.2 s, offset 0.1 s
    # Never early: each log arrives after its data time + the output latency (on the session clock).
    latency = np.array([timebase.gps_ns(now) - t for t, now in arrivals]) / NS_PER_S
    assert latency.min() >= 0.02
    assert np.median(latency) < 0.02 + 0.002 + 0.1 * SPEED  # + serial time and the test's read loop


def _relay(src: serial.Serial, dst: serial.Serial, stop: threading.Event, corrupt: bool = False) -> None:
    while not stop.is_set():
        data = src.read(4096)
        if data:
            if corrupt:  # flip one bit in every frame's payload: every CRC fails
                buf = bytearray(data)
                for i in range(len(buf)):
                    if buf[i] == 0xD3 and i + 8 < len(buf):
                        buf[i + 8] ^= 0x10
                data = bytes(buf)
            dst.write(data)


@pytest.fixture
def base(timebase: SimTimeBase, truth: GroundTruth) -> Iterator[SimBase]:
    b = SimBase("base", position=(truth.lat0_deg, truth.lon0_deg, truth.h0_m), timebase=timebase,
                clock=timebase.make_clock(speed=SPEED), station_id=42)
    b.start()
    yield b
    b.stop()


def test_rtk_fixes_only_while_corrections_arrive(make_rover: Callable[..., SimRover], open_port: Opener,
                                                 base: SimBase, truth: GroundTruth, timebase: SimTimeBase) -> None:
    rover = make_rover(rtk=FAST_RTK, clock=base.clock)
    port = open_port(rover.port_path)
    # COM2 receives raw RTCM3 only once it is set to (a port in the factory NOVATEL mode ignores it)
    assert port.command("INTERFACEMODE COM2 RTCMV3 NONE OFF").message.ok
    assert port.command("LOG BESTPOSB ONTIME 0.1").message.ok
    src = serial.Serial(base.port_path, 115200, timeout=0.02)
    dst = serial.Serial(rover.correction_port_path, 115200, timeout=0.02)
    stop = threading.Event()
    relay = threading.Thread(target=_relay, args=(src, dst, stop), name="test-relay")
    relay.start()
    try:
        def fixed(fs: list[Frame]) -> bool:
            return sum(1 for f in _logs(fs, "BESTPOS") if f.log.body.pos_type is PositionType.NARROW_INT) >= 60

        frames = port.until(fixed, timeout_s=10.0)
    finally:
        stop.set()
        relay.join(2.0)
        src.close()
    try:
        types = [f.log.body.pos_type for f in _logs(frames, "BESTPOS")]
        first_fix = types.index(PositionType.NARROW_INT)
        assert PositionType.PSRDIFF in types[:first_fix] or PositionType.NARROW_FLOAT in types[:first_fix]
        fixed = [f for f in _logs(frames, "BESTPOS") if f.log.body.pos_type is PositionType.NARROW_INT]
        horiz = []
        for f in fixed:
            body = f.log.body
            err = _enu_error(body, _truth_at(truth, timebase, f.log.header.gps_ns, LEVER_A))
            horiz.append(math.hypot(err[0], err[1]))
            # Base epoch → rover solution: 1 Hz corrections plus the relay's delay (scaled by SPEED).
            assert body.stn_id == "42" and 0.0 <= body.diff_age_s < FAST_RTK.max_correction_age_s + 1.0
        assert np.percentile(horiz, 99) < 0.05  # NARROW_INT: < 5 cm horizontal, 99 %
        # Corrections stop: fixed → float → PSRDIFF → SINGLE as the age passes 2.5, 4, 6 s.
        start = len(port.frames)
        later = port.until(lambda fs: any(f.log.body.pos_type is PositionType.SINGLE
                                          for f in _logs(fs[start:], "BESTPOS")), timeout_s=10.0)[start:]
        seq = [f.log.body.pos_type for f in _logs(later, "BESTPOS")]
        order = [t for i, t in enumerate(seq) if i == 0 or t != seq[i - 1]]
        assert order[-3:] == [PositionType.NARROW_FLOAT, PositionType.PSRDIFF, PositionType.SINGLE]
        ages = [f.log.body.diff_age_s for f in _logs(later, "BESTPOS") if f.log.body.pos_type is PositionType.PSRDIFF]
        assert max(ages) > 4.0 and ages == sorted(ages)  # the differential age keeps growing
    finally:
        dst.close()


def test_corrupt_corrections_never_fix(make_rover: Callable[..., SimRover], open_port: Opener,
                                       base: SimBase) -> None:
    rover = make_rover(rtk=RtkParams(max_correction_age_s=2.5, float_hold_s=4.0, psrdiff_timeout_s=6.0,
                                     time_to_float_s=0.0, time_to_fix_s=0.0), clock=base.clock)
    port = open_port(rover.port_path)
    assert port.command("LOG BESTPOSB ONTIME 0.5").message.ok
    src = serial.Serial(base.port_path, 115200, timeout=0.02)
    dst = serial.Serial(rover.correction_port_path, 115200, timeout=0.02)
    stop = threading.Event()
    relay = threading.Thread(target=_relay, args=(src, dst, stop, True), name="test-relay")
    relay.start()
    try:
        frames = port.until(lambda fs: len(_logs(fs, "BESTPOS")) >= 8, timeout_s=10.0)
    finally:
        stop.set()
        relay.join(2.0)
        src.close()
        dst.close()
    assert {f.log.body.pos_type for f in _logs(frames, "BESTPOS")} == {PositionType.SINGLE}
    assert rover.corrections_received == 0 and rover.port(rover.correction_port_name).bytes_read > 1000


def test_markpos_at_the_sync_pulses(make_rover: Callable[..., SimRover], open_port: Opener, truth: GroundTruth,
                                    timebase: SimTimeBase) -> None:
    sync = SyncSchedule.for_truth(timebase, 0.25, 30.0, period_s=0.5)
    rover = make_rover(sync=sync)
    port = open_port(rover.port_path)
    assert port.command("LOG MARKPOSA ONNEW").message.ok
    assert port.command("LOG MARKTIMEB ONNEW").message.ok
    frames = port.until(lambda fs: len(_logs(fs, "MARKTIME")) >= 4 and len(_logs(fs, "MARKPOS")) >= 4)
    pulses = set(sync.pulse_gps_ns)
    for f in _logs(frames, "MARKTIME"):
        body = f.log.body
        assert isinstance(body, MarkTime) and body.utc_offset_s == -18.0
        assert round(body.event_gps_ns / 1000) * 1000 in pulses  # event time = pulse time (µs)
    for f in _logs(frames, "MARKPOS"):
        assert f.log.header.gps_ns in pulses  # the header carries the event time
        body = f.log.body
        assert isinstance(body, MarkPos)
        err = _enu_error(body, _truth_at(truth, timebase, f.log.header.gps_ns, LEVER_A))
        assert math.hypot(err[0], err[1]) < 5 * math.hypot(body.lat_sigma_m, body.lon_sigma_m)
    # A time bias moves every event by that much.
    assert port.command("EVENTINCONTROL MARK1 EVENT POSITIVE 250000 4").message.ok
    start = len(port.frames)
    later = port.until(lambda fs: len(_logs(fs[start:], "MARKTIME")) >= 2)[start:]
    for f in _logs(later, "MARKTIME"):
        assert round((f.log.body.event_gps_ns - 250_000) / 1000) * 1000 in pulses
    assert port.command("EVENTINCONTROL MARK1 DISABLE").message.ok
    assert rover.next_event_ns(rover.gps_now_ns()) is None


def test_dual_antenna_heading(make_rover: Callable[..., SimRover], open_port: Opener, truth: GroundTruth,
                              timebase: SimTimeBase) -> None:
    rover = make_rover(secondary_lever_arm=LEVER_B)
    port = open_port(rover.port_path)
    assert port.command("LOG HEADINGB ONTIME 0.2").message.ok
    frames = port.until(lambda fs: len(_logs(fs, "HEADING")) >= 10)
    for f in _logs(frames, "HEADING"):
        body = f.log.body
        assert isinstance(body, Heading)
        t = timebase.truth_s(f.log.header.gps_ns)
        azimuth = math.degrees(float(np.interp(t, truth.t, np.unwrap(truth.heading_azimuth))))
        expected = (azimuth + 180.0) % 360.0  # B is behind A: the baseline points backwards
        assert abs((body.heading_deg - expected + 180) % 360 - 180) < 5 * body.heading_sigma_deg + 0.05
        assert body.length_m == pytest.approx(1.58, abs=0.02)


def _read_until_error(port: serial.Serial) -> None:
    for _ in range(50):
        port.read(100)


def test_unplug_replug_and_garbage(make_rover: Callable[..., SimRover], open_port: Opener) -> None:
    rover = make_rover()
    path = rover.port_path
    first_device = rover.device_path
    port = open_port(path)
    assert port.command("LOG BESTPOSB ONTIME 0.1").message.ok
    port.until(lambda fs: len(_logs(fs, "BESTPOS")) >= 3)
    rover.unplug()
    assert not os.path.exists(path)
    with pytest.raises(serial.SerialException):
        _read_until_error(port.port)  # the hang-up: pyserial reports the device gone
    with pytest.raises(serial.SerialException):
        serial.Serial(path, 115200, timeout=0.02)
    new_device = rover.replug()
    assert os.path.realpath(path) == new_device and new_device != first_device
    again = open_port(path)
    again.until(lambda fs: len(_logs(fs, "BESTPOS")) >= 3)  # the configuration survived the cable
    rover.inject(b"\x00garbage\xff" * 20 + b"#BESTPOSA,COM1,truncated")
    again.until(lambda fs: len(_logs(fs, "BESTPOS")) >= 6)
    assert again.framer.stats.total_skipped >= 200


def test_pause_and_unresponsive(make_rover: Callable[..., SimRover], open_port: Opener) -> None:
    rover = make_rover()
    port = open_port(rover.port_path)
    assert port.command("LOG BESTPOSB ONTIME 0.1").message.ok
    port.until(lambda fs: len(_logs(fs, "BESTPOS")) >= 2)
    rover.set_unresponsive(True)
    with pytest.raises(AssertionError, match="timed out"):
        port.command("LOG TIMEA ONCE", timeout_s=0.5)
    rover.set_unresponsive(False)
    assert port.command("LOG TIMEA ONCE").message.ok
    rover.pause_logs()
    port.until(lambda fs: not port.poll(), timeout_s=2.0)  # drained: a read returned nothing
    n = len(_logs(port.frames, "BESTPOS"))
    for _ in range(20):
        port.poll()
    assert len(_logs(port.frames, "BESTPOS")) <= n + 1
    rover.resume_logs()
    port.until(lambda fs: len(_logs(fs, "BESTPOS")) >= n + 3)


def test_stop_closes_everything(truth: GroundTruth, timebase: SimTimeBase) -> None:
    fds_before = set(os.listdir("/proc/self/fd"))
    threads_before = set(threading.enumerate())
    rover = SimRover("rover_x", truth=truth, lever_arm=LEVER_A, timebase=timebase, clock=timebase.make_clock(SPEED))
    rover.start()
    link_dir = rover.link_dir
    assert os.path.islink(rover.port_path) and os.path.islink(rover.correction_port_path)
    rover.stop()
    rover.stop()  # idempotent
    assert set(threading.enumerate()) == threads_before
    assert set(os.listdir("/proc/self/fd")) == fds_before
    assert not link_dir.exists()


def test_baud_rate_limits_and_autobaud(make_rover: Callable[..., SimRover], open_port: Opener) -> None:
    rover = make_rover(enforce_baud=True, baud=115200)
    wrong = open_port(rover.port_path, 9600)
    with pytest.raises(AssertionError, match="timed out"):
        wrong.command("LOG BESTPOSB ONTIME 0.05", timeout_s=0.5)  # wrong baud: the receiver hears noise
    wrong.port.close()
    port = open_port(rover.port_path, 115200)
    assert port.command("LOG BESTPOSB ONTIME 0.05").message.ok
    port.until(lambda fs: len(_logs(fs, "BESTPOS")) >= 5)
    assert rover.bytes_overrun() == 0
    # 20 Hz x 104 bytes needs ~21 kBd: at 9600 Bd the port overruns and logs are dropped.
    assert port.command("SERIALCONFIG COM1 9600").message.ok
    port.port.baudrate = 9600
    port.until(lambda fs: rover.bytes_overrun() > 0, timeout_s=5.0)


def test_logs_go_to_the_port_they_were_requested_on(make_rover: Callable[..., SimRover], open_port: Opener) -> None:
    rover = make_rover()
    port = open_port(rover.port_path)
    corr = open_port(rover.correction_port_path)
    assert port.command("LOG COM2 BESTPOSA ONTIME 0.1").message.ok
    assert port.command("LOG COM3 BESTVELB ONTIME 0.1").message.ok  # COM3: no cable
    assert port.command("LOG TIMEA ONTIME 0.5").message.ok
    corr.until(lambda fs: len(_logs(fs, "BESTPOS")) >= 3)
    port.until(lambda fs: len(_logs(fs, "TIME")) >= 2)
    assert all(f.log.header.port == "COM2" for f in _logs(corr.frames, "BESTPOS"))
    assert not _logs(port.frames, "BESTPOS") and not _logs(port.frames, "BESTVEL")
    assert rover.logs_unrouted >= 3
    assert ("COM3", "BESTVELB", "ONTIME", 0.1) in rover.logged()
