"""VERSION (37) and MARK1TIME (1130): the codec's layouts against the OEM7 Commands and Logs Reference and NovAtel's
EDIE both ways, and the simulated receivers on the wire: each reports its own product serial number (PSN), so
the rig can tell receivers apart, and MARK1TIME comes on the event input as MARKPOS does (MARKTIME, 231, is
deprecated)."""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from drivers.novatel import (
    BodyFormat,
    ClockModelStatus,
    ComponentType,
    Frame,
    Header,
    Mark1Time,
    MarkPos,
    MarkTime,
    RawBody,
    TimeStatus,
    Version,
    VersionComponent,
    decode_ascii,
    decode_binary,
    decode_version,
    encode_ascii,
    encode_binary,
    encode_version,
    make_header,
)
from drivers.novatel.layouts import CODECS_BY_NAME
from sim_devices.gnss import SimRover, SimTimeBase, SyncSchedule
from sim_devices.vehicle import GroundTruth
from tests.sim_gnss.conftest import SPEED, PortReader

oem = pytest.importorskip("novatel_edie.oem")

Opener = Callable[..., PortReader]
#: The MARK1TIME page's example body (its CRC, d8502226, does not verify, for EDIE either: the fields are used).
MANUAL_MARK1TIME = "1358,422621.000000500,-1.398163614e-08,7.812745577e-08,-14.000000002,VALID"
GPSCARD = VersionComponent(ComponentType.GPSCARD, "FFNRNNCBN", "BMHR17090005E", "OEM7290-1.01", "OM7MR0810RN0000",
                           "OM7BR0001RBG000", "2021/Apr/27", "13:20:06")
FPGA = VersionComponent(ComponentType.OEM7FPGA, "", "", "", "OMV070001RN0000", "", "", "")


def _edie(raw: bytes) -> Any:
    parser = oem.Parser()
    parser.write(raw)
    return parser.read()


def _header(name: str, message_id: int) -> Header:
    return Header(name, message_id, "COM1", 0, 50.0, TimeStatus.FINESTEERING, 2300, 1.0, 0, 0, 0)


# --- the codec ---------------------------------------------------------------------------------


def test_mark1time_layout_is_the_manuals() -> None:
    body = CODECS_BY_NAME["MARK1TIME"].decode_ascii(MANUAL_MARK1TIME.split(","))
    assert body == Mark1Time(1358, 422621.0000005, -1.398163614e-08, 7.812745577e-08, -14.000000002,
                             ClockModelStatus.VALID)
    assert isinstance(body, MarkTime)  # code that takes the deprecated MARKTIME takes its replacement
    raw = encode_binary(make_header(body, week=1358, seconds=422621.0), body)
    # week Long H, seconds Double H+4, offset H+8+4, offset std H+20, utc offset H+28, status Enum H+36
    assert struct.unpack_from("<HH", raw, 4)[0] == 1130 and len(raw) == 28 + 40 + 4
    assert struct.unpack_from("<iddddI", raw, 28) == (1358, 422621.0000005, -1.398163614e-08, 7.812745577e-08,
                                                      -14.000000002, 0)
    ref = _edie(raw)
    assert ref.header.message_id == 1130
    d = ref.to_dict()
    assert (d["week"], d["seconds"], d["offset"], d["offset_std"], d["utc_offset"], int(d["status"])) == (
        1358, 422621.0000005, -1.398163614e-08, 7.812745577e-08, -14.000000002, 0)
    for back in (decode_binary(bytes(ref.to_binary().message)), decode_ascii(bytes(ref.to_ascii().message))):
        assert back.body == body and back.name == "MARK1TIME"


@pytest.mark.parametrize("components", [(GPSCARD,), (GPSCARD, FPGA)])
def test_version_layout_is_the_manuals_and_edies(components: tuple[VersionComponent, ...]) -> None:
    version = Version(components)
    body = encode_version(version).data
    # a ulong count, then per component: Enum type, Char[16] model, PSN, hw, sw, boot, Char[12] date, time
    assert struct.unpack_from("<I", body)[0] == len(components) and len(body) == 4 + 108 * len(components)
    for k, c in enumerate(components):
        fields = struct.unpack_from("<I16s16s16s16s16s12s12s", body, 4 + 108 * k)
        assert fields[0] == int(c.component_type)
        assert [f.rstrip(b"\0").decode() for f in fields[1:]] == [c.model, c.psn, c.hw_version, c.sw_version,
                                                                  c.boot_version, c.compile_date, c.compile_time]
    for fmt, encode in ((BodyFormat.BINARY, encode_binary), (BodyFormat.ASCII, encode_ascii)):
        ref = _edie(encode(_header("VERSION", 37), encode_version(version, fmt)))
        got = ref.to_dict()["versions"]
        assert [(int(v["component_type"]), v["model_name"], v["psn"], v["software_version"]) for v in got] == [
            (int(c.component_type), c.model, c.psn, c.sw_version) for c in components]
        for back in (decode_binary(bytes(ref.to_binary().message)), decode_ascii(bytes(ref.to_ascii().message))):
            assert isinstance(back.body, RawBody) and decode_version(back.body) == version
    assert version.component() == GPSCARD and version.component(ComponentType.IMUCARD) is None


# --- the receivers ----------------------------------------------------------------------------------------


@pytest.fixture
def rovers(truth: GroundTruth, timebase: SimTimeBase, tmp_path: Path) -> Iterator[list[SimRover]]:
    clock = timebase.make_clock(speed=SPEED)
    sync = SyncSchedule.for_truth(timebase, 0.5, 25.0, period_s=1.0)
    made = [
        SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase, clock=clock, sync=sync),
        SimRover("rover_b", truth=truth, lever_arm=(-0.98, 0.0, 1.0), timebase=timebase, clock=clock, seed=5),
        SimRover("rover_c", truth=truth, lever_arm=(0.0, 0.0, 1.0), timebase=timebase, clock=clock,
                 serial_number="BMHR21000042E"),
    ]
    for r in made:
        r.start()
    yield made
    for r in made:
        r.stop()


def _version(port: PortReader, fmt: str) -> Version:
    assert port.command(f"LOG VERSION{fmt} ONCE").message.ok
    frames = port.until(lambda fs: any(f.log is not None and f.log.name == "VERSION" for f in fs))
    body = next(f.log.body for f in frames if f.log is not None and f.log.name == "VERSION")
    assert isinstance(body, RawBody)
    return decode_version(body)


def test_each_receiver_reports_its_own_serial_number(rovers: list[SimRover], open_port: Opener) -> None:
    psns = []
    for rover, fmt in zip(rovers, ("B", "A", ""), strict=True):
        version = _version(open_port(rover.port_path), fmt)
        card = version.component()
        assert card is not None and card.psn == rover.serial_number and card.model == rover.MODEL
        psns.append(card.psn)
    assert len(set(psns)) == 3 and psns[2] == "BMHR21000042E"
    assert all(len(p) == 13 and p.startswith("BMHR") for p in psns)


def _marks(frames: list[Frame], cls: type) -> list[Any]:
    return [f.log for f in frames if f.log is not None and type(f.log.body) is cls]


def test_mark1time_comes_on_the_event_input(rovers: list[SimRover], open_port: Opener) -> None:
    rover = rovers[0]
    assert rover.sync is not None
    port = open_port(rover.port_path)
    for cmd in ("LOG MARK1TIMEB ONNEW", "LOG MARKPOSB ONNEW", "LOG MARKTIMEA ONNEW"):
        assert port.command(cmd).message.ok, cmd
    port.until(lambda fs: len(_marks(fs, Mark1Time)) >= 3 and len(_marks(fs, MarkTime)) >= 3)
    pulses = set(rover.sync.pulse_gps_ns)
    mark1 = _marks(port.frames, Mark1Time)
    assert all(lg.header.message_id == 1130 and lg.body.event_gps_ns in pulses for lg in mark1)
    times = {lg.body.event_gps_ns for lg in mark1}
    pos_times = {lg.header.gps_ns for lg in _marks(port.frames, MarkPos)}
    assert pos_times & times and {t for t in pos_times if t <= max(times)} <= times  # the events of MARKPOS
    old = {lg.body.event_gps_ns for lg in _marks(port.frames, MarkTime)}
    assert times & old  # the deprecated log still comes, on the same events
