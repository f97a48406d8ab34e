"""Role mapping: units, validation errors, and the live decoder against known physical answers."""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import pytest
from cantools.database.can import Database

from drivers.can.checks import FrameFlag
from drivers.can.roles import (
    KNOWN_ROLES,
    UNITS,
    RoleDecoder,
    RoleMap,
    RoleSpec,
    encode_role_frame,
    unit_conversion,
)
from drivers.can.vector_decode import FrameBatch, VectorRoleDecoder
from tests.can_decode.conftest import XOR, small_roles
from vsccore.errors import ConfigError

G0 = 9.80665


@pytest.mark.parametrize(
    ("unit", "value", "si"),
    [
        ("deg/s", 180.0, math.pi),
        ("deg", 90.0, math.pi / 2),
        ("g", 1.0, G0),
        ("km/h", 36.0, 10.0),
        ("mph", 1.0, 0.44704),
        ("bar", 1.0, 1e5),
        ("mbar", 1013.25, 101325.0),
        ("kPa", 1.5, 1500.0),
        ("rpm", 60.0, 2 * math.pi),
        ("degC", 0.0, 273.15),
        ("Unit_DegreOfArcPerSecon", 1.0, math.pi / 180),  # VW DBC spelling
        ("Unit_KiloMeterPerHour", 3.6, 1.0),
        ("%", 50.0, 0.5),
    ],
)
def test_unit_table_known_answers(unit: str, value: float, si: float) -> None:
    conv = unit_conversion(unit)
    assert conv.to_si(value) == pytest.approx(si, rel=1e-12)
    assert conv.from_si(conv.to_si(value)) == pytest.approx(value, rel=1e-12)


def test_unknown_unit_suggests() -> None:
    with pytest.raises(ConfigError, match=r"roles.x.unit: unknown unit 'deg/sec2'.*did you mean") as info:
        unit_conversion("deg/sec2", where="roles.x.unit")
    assert "deg/s" in str(info.value)


def test_every_known_role_unit_is_an_si_unit_of_the_table() -> None:
    si_units = {u.si_unit for u in UNITS.values()}
    assert {"yaw_rate", "lat_accel", "swa", "wheel_speed_rr", "mc_pressure", "vsc_beta_estimate"} <= KNOWN_ROLES
    from drivers.can.roles import ROLE_SI_UNITS

    assert set(ROLE_SI_UNITS.values()) <= si_units


def test_role_map_builds_and_detects_counters(small_db: Database) -> None:
    rm = RoleMap.from_mapping(small_roles(), small_db, source="car.toml")
    assert rm.role("wheel_speed_fl").unit == "km/h"  # taken from the DBC
    assert rm.role("imu_status").unit == "1"
    imu = rm.check_for("IMU_01")
    assert imu is not None
    assert (imu.counter_signal, imu.checksum_signal, imu.algorithm) == ("IMU_Counter_BZ", "IMU_CRC", "test_xor7")
    steer = rm.check_for("STEER_01")
    assert steer is not None and steer.counter_signal == "COUNTER" and steer.algorithm == "none"
    assert rm.check_for("VSC_MUX") is None
    assert set(rm.messages) == {"IMU_01", "STEER_01", "VSC_MUX"}
    # The mapping round-trips through its own table form.
    assert RoleMap.from_mapping(rm.to_mapping(), small_db) == rm


def _with(change: dict[str, Any]) -> dict[str, Any]:
    table = copy.deepcopy(small_roles())
    for role, values in change.items():
        table["roles"].setdefault(role, {}).update(values)
    return table


def test_unknown_signal_names_role_signal_message_and_suggests(small_db: Database) -> None:
    with pytest.raises(ConfigError) as info:
        RoleMap.from_mapping(_with({"yaw_rate": {"signal": "IMU_Yawrate"}}), small_db, source="car.toml")
    text = str(info.value)
    assert "car.toml: roles.yaw_rate.signal" in text
    assert "'IMU_Yawrate'" in text and "'IMU_01'" in text and "role 'yaw_rate'" in text
    assert "did you mean 'IMU_Yaw'" in text


def test_signal_in_another_message_is_pointed_out(small_db: Database) -> None:
    with pytest.raises(ConfigError, match=r"'Wheel_FL' is in message\(s\) STEER_01"):
        RoleMap.from_mapping(_with({"yaw_rate": {"signal": "Wheel_FL"}}), small_db)


def test_unknown_message_suggests(small_db: Database) -> None:
    expected = r"roles.yaw_rate.message: message 'IMU01' is not in the DBC; did you mean 'IMU_01'"
    with pytest.raises(ConfigError, match=expected):
        RoleMap.from_mapping(_with({"yaw_rate": {"message": "IMU01"}}), small_db)


def test_unknown_key_suggests(small_db: Database) -> None:
    expected = r"roles.swa.sign_negativ_when: unknown key; did you mean 'sign_negative_when'"
    with pytest.raises(ConfigError, match=expected):
        RoleMap.from_mapping(_with({"swa": {"sign_negativ_when": 1}}), small_db)


def test_unit_of_wrong_dimension_for_known_role(small_db: Database) -> None:
    expected = r"roles.yaw_rate.unit: 'bar' converts to Pa, but role 'yaw_rate' is in rad/s"
    with pytest.raises(ConfigError, match=expected):
        RoleMap.from_mapping(_with({"yaw_rate": {"unit": "bar"}}), small_db)


def test_missing_unit_with_unrecognised_dbc_unit(small_db: Database) -> None:
    # IMU_Status has no unit in the DBC, which is fine for an extra role but not for yaw_rate.
    bad = _with({"yaw_rate": {"signal": "IMU_Status"}})
    del bad["roles"]["yaw_rate"]["unit"]
    expected = r"roles.yaw_rate.unit: missing; the DBC unit '' of IMU_01.IMU_Status converts to 1"
    with pytest.raises(ConfigError, match=expected):
        RoleMap.from_mapping(bad, small_db)


def test_bad_sign_signal_and_role_name(small_db: Database) -> None:
    expected = r"roles.swa.sign_signal: role 'swa': signal 'SWA_Sgn'.*did you mean 'SWA_Sign'"
    with pytest.raises(ConfigError, match=expected):
        RoleMap.from_mapping(_with({"swa": {"sign_signal": "SWA_Sgn"}}), small_db)
    with pytest.raises(ConfigError, match="lower-case identifiers"):
        RoleMap.from_mapping({"roles": {"Yaw Rate": {"message": "IMU_01", "signal": "IMU_Yaw"}}}, small_db)


def test_checksum_algorithm_must_support_the_message(small_db: Database) -> None:
    table = _with({})
    table["checks"] = {"IMU_01": {"checksum_signal": "IMU_CRC", "algorithm": "vw_mqb_crc8"}}
    expected = r"checks.IMU_01.algorithm: 'vw_mqb_crc8' has no parameters for IMU_01 \(0x100\)"
    with pytest.raises(ConfigError, match=expected):
        RoleMap.from_mapping(table, small_db)
    table["checks"] = {"IMU_01": {"algorithm": "crc-what"}}
    with pytest.raises(ConfigError, match="unknown checksum algorithm 'crc-what'"):
        RoleMap.from_mapping(table, small_db)


def test_valid_when_accepts_a_list(small_db: Database) -> None:
    rm = RoleMap.from_mapping(_with({"lat_accel": {"valid_when": [1, 3]}}), small_db)
    assert rm.role("lat_accel").valid_values == (1, 3)


def test_pydantic_can_config_dump_is_accepted(small_db: Database, tmp_path) -> None:
    """The session configuration's [[can]] model (rig.core.config) feeds RoleMap.from_mapping as is."""
    from rig.core.config import CanConfig

    cfg = CanConfig.model_validate({"dbc": str(tmp_path / "x.dbc"), **small_roles()})
    rm = RoleMap.from_mapping(cfg.model_dump(), small_db, key_prefix="can.vsc.")
    assert rm == RoleMap.from_mapping(small_roles(), small_db)


# --------------------------------------------------------------------------------------------
# Live decoding with frames built by cantools from chosen physical values (not by our encoder)


def _imu(db: Database, yaw_dps: float, ay_g: float, valid: int, status: int, counter: int) -> bytes:
    msg = db.get_message_by_name("IMU_01")
    values = {
        "IMU_Yaw": yaw_dps,
        "IMU_Ay": ay_g,
        "IMU_Ay_Valid": valid,
        "IMU_Status": status,
        "IMU_Counter_BZ": counter,
        "IMU_CRC": 0,
    }
    data = bytearray(msg.encode(values))
    data[7] = XOR.compute(0x100, bytes(data))
    return bytes(data)


def test_live_decoder_gives_si_values_in_iso_axes(small_db: Database) -> None:
    rm = RoleMap.from_mapping(small_roles(), small_db)
    dec = RoleDecoder(small_db, rm)
    frame = dec.decode(0x100, _imu(small_db, 10.0, -0.5, 1, 2, 0), 1_000)
    values = {s.role: s for s in frame.samples}
    # invert = true: the vehicle reports yaw rate with the opposite sign to ISO 8855.
    assert values["yaw_rate"].value == pytest.approx(-10.0 * math.pi / 180, rel=1e-12)
    assert values["yaw_rate"].unit == "rad/s"
    assert values["lat_accel"].value == pytest.approx(-0.5 * G0, rel=1e-12)
    assert values["lat_accel"].flags == FrameFlag.OK
    assert (values["imu_status"].raw, values["imu_status"].label) == (2, "fault")

    steer = small_db.get_message_by_name("STEER_01")
    data = steer.encode({"SWA_Mag": 90.0, "SWA_Sign": 1, "Wheel_FL": 36.0, "MC_Pressure": 50.0, "COUNTER": 3})
    samples = {s.role: s.value for s in dec.decode(0x200, data, 2_000).samples}
    assert samples["swa"] == pytest.approx(-math.pi / 2, rel=1e-12)
    assert samples["wheel_speed_fl"] == pytest.approx(10.0, rel=1e-12)
    assert samples["mc_pressure"] == pytest.approx(5e6, rel=1e-12)


def test_quality_bit_flags_but_keeps_the_value(small_db: Database) -> None:
    dec = RoleDecoder(small_db, RoleMap.from_mapping(small_roles(), small_db))
    frame = dec.decode(0x100, _imu(small_db, 1.0, 0.25, 0, 0, 0), 1)
    ay = next(s for s in frame.samples if s.role == "lat_accel")
    assert ay.flags == FrameFlag.INVALID
    assert ay.value == pytest.approx(0.25 * G0)


def test_bad_frames_are_flagged_without_values(small_db: Database) -> None:
    dec = RoleDecoder(small_db, RoleMap.from_mapping(small_roles(), small_db))
    good0 = _imu(small_db, 1.0, 0.1, 1, 0, 0)
    assert dec.decode(0x100, good0, 1).flags == FrameFlag.OK
    corrupt = bytearray(_imu(small_db, 1.0, 0.1, 1, 0, 1))
    corrupt[1] ^= 0x10
    bad = dec.decode(0x100, bytes(corrupt), 2)
    assert bad.flags == FrameFlag.CHECKSUM and bad.samples == ()
    # The corrupted frame did not advance the counter state: counter 1 is still in sequence.
    assert dec.decode(0x100, _imu(small_db, 1.0, 0.1, 1, 0, 1), 3).flags == FrameFlag.OK
    jump = dec.decode(0x100, _imu(small_db, 1.0, 0.1, 1, 0, 5), 4)
    assert jump.flags == FrameFlag.COUNTER and jump.samples == ()
    short = dec.decode(0x100, good0[:6], 5)
    assert short.flags == FrameFlag.WRONG_LENGTH and short.samples == ()
    unknown = dec.decode(0x7FF, b"\x00", 6)
    assert unknown.flags == FrameFlag.UNKNOWN_ID and unknown.message is None
    stats = dec.stats()
    assert stats.unknown_ids == {0x7FF: 1}
    assert dict(stats.flagged) == {"CHECKSUM": 1, "COUNTER": 1, "WRONG_LENGTH": 1, "UNKNOWN_ID": 1}
    assert (stats.frames, stats.decoded) == (6, 2)
    # Garbage of every length never raises.
    for n in range(65):
        for fill in (0x00, 0x5A, 0xFF):
            dec.decode(0x100, bytes([fill]) * n, 7)
            dec.decode(0x300, bytes([fill]) * n, 7)


def test_multiplexed_roles_and_enum_labels(small_db: Database) -> None:
    rm = RoleMap.from_mapping(small_roles(), small_db)
    dec = RoleDecoder(small_db, rm)
    mux = small_db.get_message_by_name("VSC_MUX")
    page0 = mux.encode({"Page": 0, "Beta": -0.05, "Active": 1})
    page1 = mux.encode({"Page": 1, "Mode": 2, "Active": 0})
    s0 = {s.role: s for s in dec.decode(0x300, page0, 1).samples}
    s1 = {s.role: s for s in dec.decode(0x300, page1, 2).samples}
    assert set(s0) == {"vsc_beta_estimate", "vsc_active"}
    assert s0["vsc_beta_estimate"].value == pytest.approx(-0.05)
    assert s0["vsc_active"].value == 1.0
    assert set(s1) == {"vsc_mode", "vsc_active"}
    assert (s1["vsc_mode"].raw, s1["vsc_mode"].label) == (2, "active")
    page3 = bytes([3]) + bytes(7)  # no signal is defined for page 3: cantools cannot decode it
    assert dec.decode(0x300, page3, 3).flags == FrameFlag.DECODE_ERROR

    batch = FrameBatch.from_frames([(1, 0x300, page0), (2, 0x300, page1), (3, 0x300, page3)])
    roles = VectorRoleDecoder(small_db, rm).decode(batch).roles
    beta = roles["vsc_beta_estimate"]
    assert beta.timestamps_ns.tolist() == [1, 3]  # page 1 does not carry beta; page 3 is flagged
    assert beta.values[0] == pytest.approx(-0.05) and math.isnan(beta.values[1])
    assert beta.flags.tolist() == [0, int(FrameFlag.DECODE_ERROR)]
    assert roles["vsc_mode"].labels() == ["active", None]


def test_role_spec_signal_values_inverts_to_si(small_db: Database) -> None:
    spec = RoleSpec("swa", "STEER_01", "SWA_Mag", unit="deg", sign_signal="SWA_Sign", sign_negative_when=1)
    assert spec.signal_values(-math.pi / 2) == pytest.approx({"SWA_Sign": 1, "SWA_Mag": 90.0})
    assert spec.to_si(90.0, 1) == pytest.approx(-math.pi / 2)
    assert spec.to_si(90.0, 0) == pytest.approx(math.pi / 2)


def test_encode_role_frame_decodes_back_through_cantools(small_db: Database) -> None:
    rm = RoleMap.from_mapping(small_roles(), small_db)
    data = encode_role_frame(small_db, rm, "IMU_01", {"yaw_rate": 0.2, "lat_accel": 3.0}, counter=7)
    raw = small_db.decode_message("IMU_01", data, decode_choices=False)
    assert raw["IMU_Yaw"] == pytest.approx(-0.2 * 180 / math.pi, abs=0.005)  # inverted convention
    assert raw["IMU_Ay"] == pytest.approx(3.0 / G0, abs=0.0005)
    assert raw["IMU_Ay_Valid"] == 1 and raw["IMU_Counter_BZ"] == 7
    assert raw["IMU_CRC"] == XOR.compute(0x100, data)
    assert np.isfinite(raw["IMU_Yaw"])
