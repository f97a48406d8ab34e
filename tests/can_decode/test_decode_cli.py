"""``rig can decode`` on logs in every format python-can writes, against the live per-frame decoder.

The frames are the simulated ECU's (``sim_devices.vsc_ecu.frames``) for a short step steer, with
faults added: a corrupted checksum, a truncated frame, an identifier not in the DBC, an extended
frame whose 29-bit identifier equals a base message's 11-bit one, an error frame and a remote
frame. Each log is written with python-can's own writer, decoded by the command (vectorised
path), and compared frame by frame with :class:`~drivers.can.roles.RoleDecoder` (live path, on the
frames as they were before writing).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import can
import cantools
import pytest
from typer.testing import CliRunner

from drivers.can.dbc import load_dbc
from drivers.can.logs import read_log
from drivers.can.roles import RoleDecoder, RoleMap
from rig.cli.main import app, main
from sim_devices.vehicle import make_scenario, simulate
from sim_devices.vsc_ecu import frames, vsc_sim_dbc_path
from vsccore.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
ROLES = REPO / "examples" / "roles" / "vsc_sim.toml"
runner = CliRunner()
T0 = 1_700_000_000.0


@pytest.fixture(scope="module")
def messages() -> list[can.Message]:
    truth = simulate(make_scenario("step_steer", lead_s=0.3, hold_s=0.7, speed_kmh=70))
    out = [m for _, m in frames(truth, t0_s=T0)]
    sensor = [i for i, m in enumerate(out) if m.arbitration_id == 0x101]
    status = [i for i, m in enumerate(out) if m.arbitration_id == 0x0FD]
    corrupt = out[sensor[40]]
    corrupt.data = bytearray(corrupt.data[:4]) + bytes([corrupt.data[4] ^ 0x20]) + bytearray(corrupt.data[5:])
    out[status[20]].data = out[status[20]].data[:5]
    out[status[20]].dlc = 5

    def at(i: int, **kw: object) -> can.Message:
        return can.Message(timestamp=out[i].timestamp + 1e-4, **kw)  # type: ignore[arg-type]

    extra = [
        (100, at(100, arbitration_id=0x7E8, data=b"\x02\x01\x0d", is_extended_id=False)),
        (200, at(200, arbitration_id=0x101, data=bytes(8), is_extended_id=True)),
        (250, at(250, arbitration_id=0x004, data=bytes([0, 0x10, 0, 0, 0, 0, 0, 0]), is_error_frame=True)),
        (300, at(300, arbitration_id=0x321, dlc=2, is_remote_frame=True, is_extended_id=False)),
    ]
    for i, m in sorted(extra, key=lambda x: -x[0]):
        out.insert(i + 1, m)
    return out


def _reference(messages: list[can.Message]) -> list[tuple[float, str, list[str], dict[str, float]]]:
    """What the live decoder makes of each data frame: (t, message, flags, role values)."""
    db = load_dbc(vsc_sim_dbc_path())
    dec = RoleDecoder(db, RoleMap.from_toml(ROLES, db))
    rows = []
    for m in messages:
        if m.is_error_frame or m.is_remote_frame:
            continue
        d = dec.decode(m.arbitration_id, bytes(m.data), 0, m.is_extended_id)
        if d.message is not None:
            rows.append((m.timestamp, d.message, d.flags.names(), {s.role: s.value for s in d.samples}))
    return rows


def _write(messages: list[can.Message], path: Path) -> Path:
    with can.Logger(path) as logger:
        for m in messages:
            logger.on_message_received(m)
    return path


def _decode(args: list[str]) -> tuple[str, str]:
    result = runner.invoke(app, ["can", "decode", *args])
    assert result.exit_code == 0, (result.output, result.exception)
    return result.stdout, result.stderr


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".trc", ".csv", ".db", ".mf4", ".log.gz"])
def test_roles_from_every_log_format_match_the_live_decoder(
    messages: list[can.Message], tmp_path: Path, suffix: str
) -> None:
    if suffix == ".mf4":
        pytest.importorskip("asammdf", reason="python-can reads .mf4 through asammdf (extra 'mf4')")
    log = _write(messages, tmp_path / f"drive{suffix}")
    out = tmp_path / "roles.jsonl"
    # the roles file names its DBC as package data ("pkg:sim_devices/..."): no --dbc needed
    _, summary = _decode(["--roles", str(ROLES), "--format", "jsonl", "--out", str(out), str(log)])
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    expected = _reference(messages)
    assert len(rows) == len(expected)
    t_first = int(rows[0]["t_ns"])
    for row, (t, message, flags, values) in zip(rows, expected, strict=True):
        assert (row["message"], row["flags"]) == (message, flags)
        assert row["values"] == values  # exact: JSON keeps every digit of a double
        # .asc keeps times relative to the start of the log; every format keeps them to 1 µs
        assert (int(row["t_ns"]) - t_first) / 1e9 == pytest.approx(t - expected[0][0], abs=2e-6)
    # the faults, counted in the summary: one corrupted sensor frame (then its next counter is a
    # jump), one truncated status frame (idem), and the two frames whose ids are not in the DBC
    assert "CHECKSUM 1" in summary and "COUNTER 2" in summary and "WRONG_LENGTH 1" in summary
    assert "2 with ids not in the DBC (0x7E8×1, 0x00000101x×1)" in summary
    if suffix != ".trc":  # python-can's TRC writer drops error and remote frames
        assert "2 error/remote frames skipped" in summary


def test_csv_rows_carry_si_values_units_labels_and_flags(messages: list[can.Message], tmp_path: Path) -> None:
    log = _write(messages, tmp_path / "drive.log")
    out = tmp_path / "roles.csv"
    _decode(["--roles", str(ROLES), "--out", str(out), str(log)])
    with out.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["t_s", "channel", "message", "role", "value", "unit", "label", "flags"]
    expected = _reference(messages)
    assert len(rows) == sum(len(v) or 1 for *_, v in expected)
    yaw = [r for r in rows if r["role"] == "yaw_rate"]
    assert {r["unit"] for r in yaw} == {"rad/s"}
    assert {r["flags"] for r in yaw} == {"", "INVALID"}  # quality bits while the cluster warms up
    active = [r for r in rows if r["role"] == "vsc_active"]
    assert {r["label"] for r in active} <= {"Standby", "Active"} and active
    bad = [r for r in rows if r["flags"] in ("CHECKSUM", "COUNTER", "WRONG_LENGTH")]
    assert len(bad) == 4 and all(r["role"] == "" and r["value"] == "" for r in bad)
    assert float(rows[0]["t_s"]) == pytest.approx(expected[0][0], abs=1e-6)


def test_all_signals_in_dbc_units_match_cantools(messages: list[can.Message], tmp_path: Path) -> None:
    log = _write(messages, tmp_path / "drive.log")
    out = tmp_path / "signals.jsonl"
    _decode(["--dbc", str(vsc_sim_dbc_path()), "--format", "jsonl", "--out", str(out), str(log)])
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    db = cantools.database.load_file(vsc_sim_dbc_path())  # cantools' own loader
    known = [
        m
        for m in messages
        if not (m.is_error_frame or m.is_remote_frame or m.is_extended_id) and m.arbitration_id != 0x7E8
    ]
    assert len(rows) == len(known)  # every data frame but the two whose ids are not in the DBC
    assert len(read_log(log).batch) == len(known) + 2
    for row, m in zip(rows, known, strict=True):
        assert row["id"] == m.arbitration_id
        assert row["t_ns"] == pytest.approx(m.timestamp * 1e9, abs=1_000)  # candump keeps µs
        if len(m.data) != 8:
            assert row["flags"] == ["WRONG_LENGTH"] and row["values"] == {}
            continue
        message = db.get_message_by_frame_id(m.arbitration_id)
        ref = message.decode(bytes(m.data), decode_choices=False)
        assert row["flags"] == []  # no checks without a role mapping: only the layout is decoded
        assert row["values"] == {k: float(v) for k, v in ref.items()}
        assert row["units"] == {s.name: s.unit or "" for s in message.signals if s.name in ref}


def test_a_dbc_that_does_not_parse_names_file_line_and_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = vsc_sim_dbc_path().read_text(encoding="cp1252").splitlines()
    line = next(i for i, x in enumerate(text) if "SAS_Angle :" in x)
    text[line] = text[line].replace("(0.1,0)", "(0.1;0)")
    bad = tmp_path / "broken.dbc"
    bad.write_text("\n".join(text), encoding="cp1252")
    log = tmp_path / "empty.log"
    log.write_text("")
    with pytest.raises(SystemExit) as info:
        main(["can", "decode", "--dbc", str(bad), str(log)])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"rig: error: {bad}:{line + 1}:")
    assert "DBC syntax error" in err and "0.1" in err
    # a semantic error (signals overlapping, strict check) names the line of a signal involved
    text[line] = text[line].replace("(0.1;0)", "(0.1,0)").replace("SAS_Angle : 16|16", "SAS_Angle : 8|16")
    bad.write_text("\n".join(text), encoding="cp1252")
    with pytest.raises(ConfigError, match=rf"{bad.name}:\d+: invalid DBC: .*overlapping"):
        load_dbc(bad, strict=True)


def test_unknown_log_format_and_missing_file_are_one_line_errors(tmp_path: Path) -> None:
    (tmp_path / "x.txt").write_text("")
    result = runner.invoke(app, ["can", "decode", "--dbc", str(vsc_sim_dbc_path()), str(tmp_path / "x.txt")])
    assert isinstance(result.exception, ConfigError) and ".txt" in str(result.exception)
    result = runner.invoke(app, ["can", "decode", "--dbc", str(vsc_sim_dbc_path()), str(tmp_path / "no.log")])
    assert "not found" in str(result.exception)


def test_a_session_configuration_gives_the_same_roles_as_its_roles_file(
    messages: list[can.Message], tmp_path: Path
) -> None:
    log = _write(messages, tmp_path / "drive.blf")
    a, b = tmp_path / "a.jsonl", tmp_path / "b.jsonl"
    _decode(["--roles", str(ROLES), "--format", "jsonl", "--out", str(a), str(log)])
    # sim.toml's [[can]] names the DBC as package data and roles_file = "roles/vsc_sim.toml"
    _decode(
        ["--roles", str(REPO / "examples" / "sim.toml"), "--bus", "vsc", "--format", "jsonl", "--out", str(b), str(log)]
    )
    assert a.read_text() == b.read_text()
    result = runner.invoke(
        app, ["can", "decode", "--roles", str(REPO / "examples" / "sim.toml"), "--bus", "x", str(log)]
    )
    assert isinstance(result.exception, ConfigError) and "no [[can]] bus named 'x'" in str(result.exception)
