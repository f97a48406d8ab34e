"""What a replay sends, before any bus: filters, the fault syntax, each fault kind changing exactly its signal
(checksums resealed, counters kept), and the counters of later loop passes continuing the sequence."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.can.checks import FrameFlag, VwMqbCrc8
from drivers.can.vector_decode import FrameBatch, VectorRoleDecoder
from rig.data import Session
from rig.replay.faults import Fault, FaultKind, parse_fault, parse_id
from rig.replay.plan import ReplayPlan, build_plan
from rig.replay.player import parse_bus_spec
from vsccore.errors import AnalysisError, ConfigError

CRC = VwMqbCrc8()


def _decode(session: Session, plan: ReplayPlan, name: str, data: np.ndarray) -> tuple[np.ndarray, list[dict]]:
    msg = session.dbc().get_message_by_name(name)
    rows = np.flatnonzero(plan.can_id == msg.frame_id)
    return rows, [msg.decode(bytes(data[r][: msg.length]), decode_choices=False) for r in rows]


def _changed_signals(recorded: Session, plan: ReplayPlan, name: str) -> tuple[np.ndarray, list[set[str]]]:
    rows, before = _decode(recorded, plan, name, plan.recorded)
    _rows, after = _decode(recorded, plan, name, plan.data)
    return rows, [{k for k in b if b[k] != a[k]} for b, a in zip(before, after, strict=True)]


def _only_message_changed(plan: ReplayPlan, frame_id: int) -> None:
    other = plan.can_id != frame_id
    assert np.array_equal(plan.data[other], plan.recorded[other])


# --- syntax ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("text", "want"), [
    ("yaw_rate:offset=0.05", Fault("yaw_rate", FaultKind.OFFSET, 0.05)),
    ("swa:freeze@12.0", Fault("swa", FaultKind.FREEZE, 0.0, 12.0)),
    ("wheel_speed_fl:dropout@10..12", Fault("wheel_speed_fl", FaultKind.DROPOUT, 0.0, 10.0, 12.0)),
    ("ESC_SensorCluster.ESC_LatAccel:offset=-0.01@0.5..1.5",
     Fault("ESC_SensorCluster.ESC_LatAccel", FaultKind.OFFSET, -0.01, 0.5, 1.5)),
    ("yaw_rate:dropout=0.1@3", Fault("yaw_rate", FaultKind.DROPOUT, 0.1, 3.0, math.inf)),
])
def test_fault_syntax(text: str, want: Fault) -> None:
    assert parse_fault(text) == want
    assert parse_fault(str(want)) == want  # str() writes the same syntax back


@pytest.mark.parametrize(("text", "match"), [
    ("yaw_rate", "expected TARGET:KIND"),
    ("yaw_rate:wobble=1", "unknown fault kind 'wobble'"),
    ("yaw_rate:offset", "offset needs a value"),
    ("yaw_rate:offset=abc", "value 'abc' is not a number"),
    ("swa:freeze=3@1", "freeze takes no value"),
    ("swa:freeze@5..2", "window 5..2"),
    ("swa:freeze@", "expected TARGET:KIND"),
    ("yaw_rate:offset=inf", "not finite"),
])
def test_bad_fault_text_is_a_config_error_naming_it(text: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match) as info:
        parse_fault(text)
    assert repr(text) in str(info.value)


def test_bus_specs() -> None:
    cfg = parse_bus_spec("socketcand:vsc0,host=127.0.0.1,port=29536")
    assert (cfg.interface, cfg.channel) == ("socketcand", "vsc0")
    assert dict(cfg.options) == {"host": "127.0.0.1", "port": 29536}
    cfg = parse_bus_spec("pcan:PCAN_USBBUS1,bitrate=250000,auto_reset=true")
    assert (cfg.bitrate, dict(cfg.options)) == (250_000, {"auto_reset": True})
    with pytest.raises(ConfigError, match="INTERFACE:CHANNEL"):
        parse_bus_spec("can0")
    with pytest.raises(ConfigError, match="'bitrate' is not KEY=VALUE"):
        parse_bus_spec("socketcan:can0,bitrate")


def test_bus_spec_from_a_session_configuration() -> None:
    from rig.workflows.demo import demo_config_path

    cfg = parse_bus_spec(str(demo_config_path()))
    assert (cfg.interface, cfg.channel, cfg.bitrate) == ("virtual", "vsc-sim", 500_000)
    with pytest.raises(ConfigError, match="no \\[\\[can\\]\\] table named 'chassis'"):
        parse_bus_spec(f"{demo_config_path()}#chassis")


# --- filters -----------------------------------------------------------------------------------------


def test_filters_by_id_message_name_and_role(recorded: Session) -> None:
    db = recorded.dbc()
    assert parse_id("0x101", db) == 0x101 and parse_id("SAS_Steering", db) == 0x86
    assert parse_id("0x18FF0001", None) == 0x18FF0001 | 0x8000_0000
    plan = build_plan(recorded, ids=["0x101", "SAS_Steering"])
    assert set(plan.can_id.tolist()) == {0x101, 0x86}
    all_ids = recorded.can_frames("vsc").records["can_id"]
    assert len(plan) == int(np.isin(all_ids, [0x101, 0x86]).sum())
    # the schedule still counts from the bus's first frame, whatever the filter keeps
    plan_roles = build_plan(recorded, roles=["wheel_speed_fl", "vsc_beta_estimate"])
    assert set(plan_roles.can_id.tolist()) == {0xB2, 0xFD}
    with pytest.raises(ConfigError, match="'Nope'"):
        build_plan(recorded, ids=["Nope"])
    with pytest.raises(ConfigError, match="role 'yaw_rat' is not mapped; did you mean 'yaw_rate'"):
        build_plan(recorded, roles=["yaw_rat"])
    with pytest.raises(AnalysisError, match="no frame left"):
        build_plan(recorded, ids=["0x7FF"])


# --- faults --------------------------------------------------------------------------------------------


def test_offset_in_si_changes_only_the_signal_and_reseals_the_checksum(recorded: Session) -> None:
    plan = build_plan(recorded, faults=[parse_fault("yaw_rate:offset=0.05@0.5..1.5")])
    rows, changed = _changed_signals(recorded, plan, "ESC_SensorCluster")
    t = plan.t_ns[rows] / 1e9
    inside = (t >= 0.5) & (t < 1.5)
    assert all(c == {"ESC_YawRate", "CHECKSUM"} for c, i in zip(changed, inside, strict=True) if i)
    assert not any(c for c, i in zip(changed, inside, strict=True) if not i)
    assert np.array_equal(plan.rewritten, np.isin(np.arange(len(plan)), rows[inside]))
    _only_message_changed(plan, 0x101)
    for r in rows:  # every frame of the message carries a valid checksum and its recorded counter
        assert plan.data[r][0] == CRC.compute(0x101, bytes(plan.data[r][:8]))
        assert plan.data[r][1] & 0x0F == plan.recorded[r][1] & 0x0F
    db = recorded.dbc()
    roles = VectorRoleDecoder(db, recorded.rolemap(db, "vsc"))
    batch = FrameBatch(plan.t_ns, plan.can_id, plan.data, plan.length.astype(np.int16))
    before = FrameBatch(plan.t_ns, plan.can_id, plan.recorded, plan.length.astype(np.int16))
    got, want = roles.decode(batch).roles["yaw_rate"], roles.decode(before).roles["yaw_rate"]
    assert not (got.flags & int(FrameFlag.frame_level())).any()  # INVALID: the cluster's warm-up, as recorded
    d = got.values - want.values
    lsb = math.radians(0.01)
    assert np.all(np.abs(d[inside] - 0.05) <= lsb / 2 + 1e-12) and np.all(d[~inside] == 0)


def test_offset_through_an_inverted_role(recorded: Session) -> None:
    """swa is positive clockwise on this car (invert = true): +0.1 rad in ISO 8855 is -5.73 deg on the wire."""
    plan = build_plan(recorded, faults=[parse_fault("swa:offset=0.1")])
    _rows, before = _decode(recorded, plan, "SAS_Steering", plan.recorded)
    _rows, after = _decode(recorded, plan, "SAS_Steering", plan.data)
    for b, a in zip(before, after, strict=True):
        assert a["SAS_Angle"] - b["SAS_Angle"] == pytest.approx(-math.degrees(0.1), abs=0.051)
        assert {k for k in b if b[k] != a[k]} <= {"SAS_Angle", "CHECKSUM"}


def test_freeze_holds_the_last_value_before_the_window(recorded: Session) -> None:
    plan = build_plan(recorded, faults=[parse_fault("swa:freeze@0.4..1.0")])
    rows, after = _decode(recorded, plan, "SAS_Steering", plan.data)
    _rows, before = _decode(recorded, plan, "SAS_Steering", plan.recorded)
    t = plan.t_ns[rows] / 1e9
    inside = np.flatnonzero((t >= 0.4) & (t < 1.0))
    held = before[inside[0] - 1]["SAS_Angle"]
    assert len({before[k]["SAS_Angle"] for k in inside}) > 1, "the step steer moves the wheel in the window"
    assert all(after[k]["SAS_Angle"] == held for k in inside)
    assert all(after[k] == before[k] for k in range(len(rows)) if k not in set(inside.tolist()))
    _only_message_changed(plan, 0x86)


def test_dropout_zeroes_the_signal_and_marks_its_quality_bit(recorded: Session) -> None:
    plan = build_plan(recorded, faults=[parse_fault("yaw_rate:dropout@0.5..1.0")])
    rows, changed = _changed_signals(recorded, plan, "ESC_SensorCluster")
    _rows, after = _decode(recorded, plan, "ESC_SensorCluster", plan.data)
    t = plan.t_ns[rows] / 1e9
    for k in np.flatnonzero((t >= 0.5) & (t < 1.0)):
        assert after[k]["ESC_YawRate"] == 0 and after[k]["ESC_YawRate_QBit"] == 1
        assert changed[k] <= {"ESC_YawRate", "ESC_YawRate_QBit", "CHECKSUM"}


def test_dropout_of_a_wheel_speed_touches_no_other_wheel(recorded: Session) -> None:
    """ESC_WheelSpeeds has neither counter nor checksum: only FL's 16 bits change."""
    plan = build_plan(recorded, faults=[parse_fault("wheel_speed_fl:dropout@0.2..1.2")])
    rows, changed = _changed_signals(recorded, plan, "ESC_WheelSpeeds")
    t = plan.t_ns[rows] / 1e9
    inside = (t >= 0.2) & (t < 1.2)
    assert all(c == {"ESC_WheelSpeed_FL"} for c, i in zip(changed, inside, strict=True) if i)
    assert not any(c for c, i in zip(changed, inside, strict=True) if not i)
    assert np.array_equal(plan.data[rows][:, 2:], plan.recorded[rows][:, 2:])


def test_a_signal_by_name_in_dbc_units_and_clipping_to_the_dbc_range(recorded: Session) -> None:
    plan = build_plan(recorded, faults=[parse_fault("ESC_SensorCluster.ESC_LatAccel:offset=100")])
    _rows, after = _decode(recorded, plan, "ESC_SensorCluster", plan.data)
    assert all(a["ESC_LatAccel"] == pytest.approx(3.2767) for a in after)  # clipped at the DBC maximum


def test_fault_targets_are_checked(recorded: Session) -> None:
    with pytest.raises(ConfigError, match="role 'yaw' is not mapped"):
        build_plan(recorded, faults=[parse_fault("yaw:offset=1")])
    with pytest.raises(ConfigError, match="signal 'Nope' is not in message ESC_SensorCluster"):
        build_plan(recorded, faults=[parse_fault("ESC_SensorCluster.Nope:offset=1")])
    with pytest.raises(ConfigError, match="no frame of ESC_SensorCluster"):
        build_plan(recorded, ids=["0x86"], faults=[parse_fault("yaw_rate:offset=1")])


# --- loops ---------------------------------------------------------------------------------------------


def test_later_passes_continue_every_counter_with_valid_checksums(recorded: Session) -> None:
    plan = build_plan(recorded)
    p0, p1, p2 = plan.payloads(0), plan.payloads(1), plan.payloads(2)
    assert np.array_equal(p0, plan.recorded)
    for ident in (0x86, 0x101, 0x106, 0xFD):
        rows = np.flatnonzero(plan.can_id == ident)
        seq = np.concatenate([p[rows][:, 1] & 0x0F for p in (p0, p1, p2)]).astype(int)
        assert np.all(np.diff(seq) % 16 == 1), f"0x{ident:X}: counter jumps {np.unique(np.diff(seq) % 16)}"
        for p in (p1, p2):
            assert all(p[r][0] == CRC.compute(ident, bytes(p[r][:8])) for r in rows)
            assert np.array_equal(p[rows][:, 2:], p0[rows][:, 2:])  # nothing else changes
    plain = np.isin(plan.can_id, [0xB2, 0x5A0])
    assert np.array_equal(p1[plain], p0[plain])
