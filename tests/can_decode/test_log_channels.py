"""CAN logs with several channels, candump's screen output, ``.mf4`` without asammdf, and DBC signals that lie
outside their message.

The frames are the simulated ECU's (``sim_devices.vsc_ecu.frames``) for a short step steer. A two-channel log
carries the ECU's frames on channel 1 and the same frames 0.3 ms later on channel 2, so decoding both channels as
one bus sees every counter repeat (a counter jump); decoded channel by channel, none.
"""

from __future__ import annotations

import csv
import json
import logging
import sys
from pathlib import Path

import can
import pytest
from typer.testing import CliRunner

from drivers.can.dbc import load_dbc, parse_dbc_text, signal_last_byte, signals_outside_message
from drivers.can.logs import MF4_EXTRA, batch_from_messages, iter_log, read_log
from drivers.can.vector_decode import VectorDecoder
from rig.cli.main import app, main
from sim_devices.vehicle import make_scenario, simulate
from sim_devices.vsc_ecu import frames, vsc_sim_dbc_path
from tests.can_decode.test_decode_cli import _decode, _write
from vsccore.errors import ConfigError, DecodeError

REPO = Path(__file__).resolve().parents[2]
ROLES = REPO / "examples" / "roles" / "vsc_sim.toml"
SMALL_DBC = Path(__file__).parent / "data" / "small.dbc"
runner = CliRunner()
T0 = 1_700_000_000.0


@pytest.fixture(scope="module")
def ecu() -> list[can.Message]:
    truth = simulate(make_scenario("step_steer", lead_s=0.3, hold_s=0.4, speed_kmh=70))
    return [m for _, m in frames(truth, t0_s=T0)]


def _two_channels(ecu: list[can.Message]) -> list[can.Message]:
    out: list[can.Message] = []
    for m in ecu:
        out.append(can.Message(timestamp=m.timestamp, arbitration_id=m.arbitration_id, data=bytes(m.data),
                               is_extended_id=m.is_extended_id, channel=0))
        # the same frame again on the second channel, one frame late: on one bus every counter repeats
        out.append(can.Message(timestamp=m.timestamp + 3e-4, arbitration_id=m.arbitration_id, data=bytes(m.data),
                               is_extended_id=m.is_extended_id, channel=1))
    return out


def _jsonl(path: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_each_channel_is_decoded_on_its_own_with_a_channel_column(
    ecu: list[can.Message], tmp_path: Path, suffix: str
) -> None:
    log = _write(_two_channels(ecu), tmp_path / f"two{suffix}")
    assert read_log(log).channel_names() == ["1", "2"]  # as the log and CANalyzer number them
    out = tmp_path / "roles.jsonl"
    _, summary = _decode(["--roles", str(ROLES), "--format", "jsonl", "--out", str(out), str(log)])
    rows = _jsonl(out)
    one = [r for r in rows if r["channel"] == "1"]
    two = [r for r in rows if r["channel"] == "2"]
    assert len(one) == len(two) == len(rows) // 2 > 100
    # decoded as one bus, every repeated frame would be a counter jump (the old behaviour: COUNTER in the flags)
    assert "COUNTER" not in summary and all("COUNTER" not in r["flags"] for r in rows)  # type: ignore[operator]
    assert [r["values"] for r in one] == [r["values"] for r in two]
    assert "channels 1, 2" in summary
    # --channel keeps one channel; the CSV has the channel column
    csv_out = tmp_path / "two.csv"
    _, summary = _decode(["--roles", str(ROLES), "--channel", "2", "--out", str(csv_out), str(log)])
    with csv_out.open(newline="") as fh:
        got = list(csv.DictReader(fh))
    assert list(got[0]) == ["t_s", "channel", "message", "role", "value", "unit", "label", "flags"]
    assert {r["channel"] for r in got} == {"2"} and f"{len(one)} decoded frames written" in summary
    assert f"{len(ecu)} frames on channels not selected" in summary


def test_an_unknown_channel_is_a_clear_error(ecu: list[can.Message], tmp_path: Path) -> None:
    log = _write(_two_channels(ecu[:20]), tmp_path / "two.asc")
    result = runner.invoke(app, ["can", "decode", "--dbc", str(vsc_sim_dbc_path()), "--channel", "3", str(log)])
    assert isinstance(result.exception, ConfigError)
    assert "no frames on channel(s) 3" in str(result.exception) and "'1', '2'" in str(result.exception)


def test_a_channel_map_gives_each_channel_its_dbc(ecu: list[can.Message], tmp_path: Path) -> None:
    """Channel 1 carries the VSC ECU (vsc_sim.dbc), channel 2 another bus whose ids mean other messages
    (small.dbc); channel 3 is not in the map."""
    small = load_dbc(SMALL_DBC)
    steer = small.get_message_by_name("STEER_01")
    other = [can.Message(timestamp=T0 + 0.01 * i, arbitration_id=steer.frame_id, channel=1,
                         data=steer.encode({"SWA_Mag": 10.0 + i, "SWA_Sign": 0, "Wheel_FL": 50.0, "MC_Pressure": 5.0,
                                            "COUNTER": i % 16}), is_extended_id=False) for i in range(30)]
    third = [can.Message(timestamp=T0 + 0.5, arbitration_id=0x101, data=bytes(8), channel=2)]
    first = [can.Message(timestamp=m.timestamp, arbitration_id=m.arbitration_id, data=bytes(m.data), channel=0,
                         is_extended_id=m.is_extended_id) for m in ecu[:200]]
    log = _write(sorted(first + other + third, key=lambda m: m.timestamp), tmp_path / "three.blf")
    (tmp_path / "dbc").mkdir()
    (tmp_path / "dbc" / "chassis.dbc").write_bytes(SMALL_DBC.read_bytes())
    cmap = tmp_path / "channels.toml"
    cmap.write_text('[channels.1]\ndbc = "pkg:sim_devices/data/vsc_sim.dbc"\n\n'
                    '[channels."2"]\ndbc = "dbc/chassis.dbc"\n')
    out = tmp_path / "signals.jsonl"
    _, summary = _decode(["--channel-map", str(cmap), "--format", "jsonl", "--out", str(out), str(log)])
    rows = _jsonl(out)
    by_channel: dict[object, set[object]] = {}
    for r in rows:
        by_channel.setdefault(r["channel"], set()).add(r["message"])
    vsc = load_dbc(vsc_sim_dbc_path())
    assert by_channel["1"] <= {m.name for m in vsc.messages} and by_channel["2"] == {"STEER_01"}
    swa = [r["values"]["SWA_Mag"] for r in rows if r["channel"] == "2"]  # type: ignore[index]
    assert swa == pytest.approx([10.0 + i for i in range(30)])
    assert "1 frames on channel '3' not decoded (not in the channel map)" in summary
    # a map entry without a DBC, and a map mixed with --dbc, are one-line errors naming the key
    cmap.write_text('[channels.1]\nroles_file = "x.toml"\n')
    result = runner.invoke(app, ["can", "decode", "--channel-map", str(cmap), str(log)])
    assert isinstance(result.exception, ConfigError) and "channels.1: unknown key(s) roles_file" in str(
        result.exception)
    result = runner.invoke(app, ["can", "decode", "--channel-map", str(cmap), "--dbc", str(SMALL_DBC), str(log)])
    assert isinstance(result.exception, ConfigError) and "not both" in str(result.exception)


def test_a_channel_map_with_roles(ecu: list[can.Message], tmp_path: Path) -> None:
    log = _write(_two_channels(ecu), tmp_path / "two.asc")
    cmap = tmp_path / "channels.toml"
    cmap.write_text(f'[channels.2]\nroles = "{ROLES}"\n')
    out = tmp_path / "roles.jsonl"
    _, summary = _decode(["--channel-map", str(cmap), "--format", "jsonl", "--out", str(out), str(log)])
    rows = _jsonl(out)
    assert {r["channel"] for r in rows} == {"2"} and any("yaw_rate" in r["values"] for r in rows)  # type: ignore
    assert f"{len(ecu)} frames on channel '1' not decoded" in summary


def _screen_line(m: can.Message, with_time: bool = True) -> str:
    """One frame as ``candump -t a`` prints it on a terminal (candump.c: ' (%010lu.%06lu) ', the device name
    right-aligned, then the id as %3X or %8X, '   [%d]  ' and the bytes as '%02X ')."""
    ident = f"{m.arbitration_id:08X}" if m.is_extended_id else f"{m.arbitration_id:03X}"
    if m.is_remote_frame:
        body = "remote request"
    else:
        body = " ".join(f"{b:02X}" for b in m.data)
    stamp = f" ({m.timestamp:017.6f}) " if with_time else "  "
    return f"{stamp}{m.channel:>5}  {ident}   [{m.dlc}]  {body}"


def test_candump_screen_output_reads_like_the_log_format(ecu: list[can.Message], tmp_path: Path) -> None:
    msgs = [can.Message(timestamp=round(m.timestamp, 6), arbitration_id=m.arbitration_id, data=bytes(m.data),
                        is_extended_id=m.is_extended_id, channel="vcan0") for m in ecu]
    msgs.insert(50, can.Message(timestamp=msgs[50].timestamp, arbitration_id=0x321, dlc=2, is_remote_frame=True,
                                channel="vcan0"))
    msgs.insert(60, can.Message(timestamp=msgs[60].timestamp, arbitration_id=0x18FEF100, data=b"\x01\x02\x03",
                                is_extended_id=True, channel="vcan1"))
    screen = tmp_path / "screen.log"
    screen.write_text("\n".join(_screen_line(m) for m in msgs) + "\n")
    reference = _write(msgs, tmp_path / "candump.log")  # python-can's candump -L writer
    got = list(iter_log(screen))
    assert len(got) == len(msgs)
    for a, b in zip(got, iter_log(reference), strict=True):
        assert (a.timestamp, a.arbitration_id, a.is_extended_id, bytes(a.data), a.channel, a.is_remote_frame) == (
            b.timestamp, b.arbitration_id, b.is_extended_id, bytes(b.data), b.channel, b.is_remote_frame)
    a_out, b_out = tmp_path / "a.jsonl", tmp_path / "b.jsonl"
    _decode(["--roles", str(ROLES), "--format", "jsonl", "--out", str(a_out), str(screen)])
    _decode(["--roles", str(ROLES), "--format", "jsonl", "--out", str(b_out), str(reference)])
    assert a_out.read_text() == b_out.read_text() and a_out.read_text()


def test_candump_screen_output_without_times_is_a_clear_error(
    ecu: list[can.Message], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    screen = tmp_path / "screen.log"
    msgs = [can.Message(arbitration_id=m.arbitration_id, data=bytes(m.data), channel="vcan0") for m in ecu[:5]]
    screen.write_text("\n".join(_screen_line(m, with_time=False) for m in msgs) + "\n")
    with pytest.raises(SystemExit) as info:
        main(["can", "decode", "--dbc", str(vsc_sim_dbc_path()), str(screen)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert f"{screen}:1: candump screen output without timestamps" in err and "candump -t a" in err
    assert "too many values to unpack" not in err
    # a delta-time capture (-t d) runs backwards and is named as such
    lines = [_screen_line(can.Message(timestamp=t, arbitration_id=0x101, data=bytes(8), channel="vcan0"))
             for t in (0.0, 0.01, 0.002)]
    screen.write_text("\n".join(lines) + "\n")
    with pytest.raises(DecodeError, match=r":3: timestamp .* runs backwards \(a 'candump -t d'"):
        read_log(screen)


def test_mf4_without_asammdf_names_the_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    log = tmp_path / "drive.mf4"
    log.write_bytes(b"MDF     4.10    ")
    monkeypatch.setitem(sys.modules, "asammdf", None)  # import asammdf now raises ImportError
    with pytest.raises(ConfigError, match=r"install the vsc-rig\[mf4\] extra") as info:
        read_log(log)
    assert MF4_EXTRA == "vsc-rig[mf4]" and str(log) in str(info.value)


_DBC = """VERSION ""

NS_ :

BS_:

BU_: ECU

BO_ 291 SHORT_MSG: {length} ECU
 SG_ Inside : 0|16@1+ (1,0) [0|65535] "" ECU
 SG_ {name} : {start}|{bits}@{order}+ (0.5,0) [0|1000] "km/h" ECU
"""


def test_a_signal_outside_its_message_warns_once_at_load(caplog: pytest.LogCaptureFixture) -> None:
    text = _DBC.format(length=6, name="Speed", start=48, bits=16, order=1)  # bytes 6-7 of a 6-byte message
    with caplog.at_level(logging.WARNING, logger="drivers.can.dbc"):
        db = parse_dbc_text(text, source="cut.dbc")
    warnings = [r.getMessage() for r in caplog.records if r.name == "drivers.can.dbc"]
    assert len(warnings) == 1
    assert warnings[0].startswith("cut.dbc: 1 DBC signal lies outside its message's length")
    assert "SHORT_MSG.Speed (line 11)" in warnings[0]
    assert signals_outside_message(db) == ["SHORT_MSG.Speed"]
    # what the warning is about: the signal decodes from the zero padding, whatever the frame says
    batch = batch_from_messages([can.Message(timestamp=T0, arbitration_id=291, data=bytes([1, 2, 3, 4, 5, 6]),
                                             is_extended_id=False)]).batch
    decoded = VectorDecoder(db).decode(batch).messages["SHORT_MSG"]
    assert decoded.flags.tolist() == [0] and decoded.values["Speed"].tolist() == [0.0]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="drivers.can.dbc"):
        parse_dbc_text(_DBC.format(length=8, name="Speed", start=48, bits=16, order=1), source="ok.dbc")
        load_dbc(vsc_sim_dbc_path())
    assert not [r for r in caplog.records if r.name == "drivers.can.dbc"]


def test_signal_extent_agrees_with_cantools_strict_check() -> None:
    """Intel and Motorola layouts: the loader's 'outside' verdict is exactly cantools' strict 'does not fit'."""
    checked = outside = 0
    for order in (0, 1):
        for start in range(64):
            for bits in (1, 3, 8, 12, 16):
                text = _DBC.format(length=6, name="Sig", start=start, bits=bits, order=order)
                try:
                    parse_dbc_text(text, strict=True)
                except ConfigError as exc:
                    # cantools' strict mode also rejects signals overlapping 'Inside' (bytes 0-1): skip those
                    if "overlap" in str(exc).lower():
                        continue
                    fits = False
                else:
                    fits = True
                last = signal_last_byte(start, bits, "big_endian" if order == 0 else "little_endian")
                if order == 0 and (start // 8) * 8 + (7 - start % 8) + bits - 1 >= 64:
                    continue  # runs past any 8-byte frame: not a layout anyone writes
                assert (last >= 6) == (not fits), (order, start, bits)
                checked += 1
                outside += not fits
    assert checked > 400 and outside > 50


def test_screen_reader_rejects_garbage_with_the_line(tmp_path: Path) -> None:
    screen = tmp_path / "screen.log"
    good = _screen_line(can.Message(timestamp=T0, arbitration_id=0x101, data=bytes(8), channel="vcan0"))
    screen.write_text(good + "\n" + "this is not a frame\n")
    with pytest.raises(DecodeError, match=r"screen\.log:2: not a candump screen line"):
        read_log(screen)
