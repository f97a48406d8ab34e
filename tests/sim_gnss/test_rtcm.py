"""RTCM3 encoders checked by decoding with pyrtcm (an independent implementation)."""

from __future__ import annotations

import datetime as dt

import pymap3d
import pytest
from pyrtcm import RTCMReader

from drivers.novatel import crc24q
from sim_devices.gnss.antenna import FixedAntenna
from sim_devices.gnss.constellation import SPEED_OF_LIGHT, Constellation, GnssSystem
from sim_devices.gnss.observations import ObservationGenerator
from sim_devices.gnss.rtcm import (
    MsmSatellite,
    MsmSignal,
    encode_1005,
    encode_1006,
    encode_1033,
    encode_1230,
    encode_msm,
    frame,
    frame_gps_epoch_ms,
    frame_message_number,
    frame_station_id,
    glonass_epoch,
    lock_indicator_msm4,
    lock_indicator_msm7,
)

ARP = pymap3d.geodetic2ecef(48.7758, 9.1829, 347.9)
T_NS = (2400 * 604800 + 345601) * 1_000_000_000
LIGHT_MS = SPEED_OF_LIGHT * 1e-3


def _parse(payload: bytes):
    raw = frame(payload)
    assert crc24q(raw) == 0
    return raw, RTCMReader.parse(raw)  # validates the CRC too


def test_station_messages() -> None:
    raw, m = _parse(encode_1005(1234, ARP))
    assert m.identity == "1005" and m.DF003 == 1234
    assert pytest.approx(ARP, abs=1e-4) == (m.DF025, m.DF026, m.DF027)
    assert m.DF022 == 1 and m.DF023 == 1
    assert frame_message_number(raw) == 1005 and frame_station_id(raw) == 1234
    _, m = _parse(encode_1006(7, ARP, antenna_height_m=1.234))
    assert m.identity == "1006" and pytest.approx(1.234, abs=1e-4) == m.DF028
    assert pytest.approx(ARP, abs=1e-4) == (m.DF025, m.DF026, m.DF027)


def test_1033_and_1230() -> None:
    _, m = _parse(encode_1033(7, antenna_descriptor="NOV850", receiver_type="NOVATEL OEM729", firmware="OM7"))
    assert m.DF029 == 6 and "".join(getattr(m, f"DF030_{i:02d}") for i in range(1, 7)) == "NOV850"
    assert "".join(getattr(m, f"DF228_{i:02d}") for i in range(1, m.DF227 + 1)) == "NOVATEL OEM729"
    _, m = _parse(encode_1230(7, (1.0, None, -2.0, 0.5), aligned=True))
    assert (m.DF421, m.DF422_1, m.DF422_2, m.DF422_3, m.DF422_4) == (1, 1, 0, 1, 1)
    assert pytest.approx((1.0, -2.0, 0.5)) == (m.DF423, m.DF425, m.DF426)


def _satellites(system: GnssSystem) -> list[MsmSatellite]:
    gen = ObservationGenerator(Constellation(), seed=2)
    obs = [o for o in gen.epoch(FixedAntenna(48.7758, 9.1829, 347.9).state(0.0), T_NS) if o.sat.system is system]
    by_prn: dict[int, list] = {}
    for o in obs:
        by_prn.setdefault(o.sat.prn, []).append(o)
    return [
        MsmSatellite(prn, tuple(MsmSignal(o.msm_signal_id, o.pseudorange_m, o.phaserange_m, o.range_rate_mps,
                                          o.cnr_dbhz, 120.0) for o in sigs),
                     sigs[0].pseudorange_m, sigs[0].range_rate_mps, sigs[0].sat.fcn)
        for prn, sigs in sorted(by_prn.items())
    ]


@pytest.mark.parametrize(("msm", "system"), [(4, GnssSystem.GPS), (7, GnssSystem.GPS), (4, GnssSystem.GLONASS),
                                             (7, GnssSystem.GLONASS)])
def test_msm_decodes_to_the_observations(msm: int, system: GnssSystem) -> None:
    sats = _satellites(system)
    assert len(sats) >= 4
    raw, m = _parse(encode_msm(msm, system, 7, T_NS, sats, multiple_message=True))
    assert int(m.identity) == (1070 if system is GnssSystem.GPS else 1080) + msm
    assert m.NSat == len(sats) and m.NSig == 2 and m.NCell == 2 * len(sats) and m.DF393 == 1
    if system is GnssSystem.GPS:
        assert m.DF004 == 345601 * 1000
        assert frame_gps_epoch_ms(raw) == 345601 * 1000
    else:
        dow, ms = glonass_epoch(T_NS, 18)
        assert (dow, ms) == (m.DF416, m.DF034)
    fine_pr, fine_ph = ("DF405", "DF406") if msm == 7 else ("DF400", "DF401")
    tol = 1e-3 if msm == 7 else 0.02  # resolution 2^-29 ms (0.6 mm) or 2^-24 ms (1.8 cm)
    cell = 0
    for i, sat in enumerate(sats, start=1):
        assert int(getattr(m, f"PRN_{i:02d}")) == sat.sat_id
        rough = getattr(m, f"DF397_{i:02d}") + getattr(m, f"DF398_{i:02d}")
        if msm == 7 and system is GnssSystem.GLONASS:
            assert getattr(m, f"DF419_{i:02d}") == sat.glonass_fcn + 7
        for sig in sat.signals:
            cell += 1
            pr = (rough + getattr(m, f"{fine_pr}_{cell:02d}")) * LIGHT_MS
            ph = (rough + getattr(m, f"{fine_ph}_{cell:02d}")) * LIGHT_MS
            assert pr == pytest.approx(sig.pseudorange_m, abs=tol)
            assert ph == pytest.approx(sig.phaserange_m, abs=tol)
            assert 19.0e6 < pr < 26.5e6  # a MEO satellite's range
            if msm == 7:
                rate = getattr(m, f"DF399_{i:02d}") + getattr(m, f"DF404_{cell:02d}")
                assert rate == pytest.approx(sig.phaserange_rate_mps, abs=2e-4)


def test_lock_time_indicators_are_monotonic_and_match_the_tables() -> None:
    assert [lock_indicator_msm4(t) for t in (0, 31, 32, 64, 127, 128, 600_000)] == [0, 0, 1, 2, 2, 3, 15]
    # DF407: t = i below 64 ms, then 2i − 64 (64..95), 4i − 256 (96..127) ...
    assert [lock_indicator_msm7(t) for t in (10, 64, 96, 128, 256)] == [10, 64, 80, 96, 128]
    values = [lock_indicator_msm7(t) for t in range(0, 300_000, 97)]
    assert values == sorted(values) and max(values) <= 704


def test_glonass_epoch_is_moscow_time_of_day() -> None:
    moscow = dt.datetime(1980, 1, 6, tzinfo=dt.UTC) + dt.timedelta(weeks=2400, seconds=345601 - 18, hours=3)
    dow, ms = glonass_epoch(T_NS, 18)
    assert dow == (moscow.weekday() + 1) % 7  # 0 = Sunday
    assert ms == ((moscow.hour * 60 + moscow.minute) * 60 + moscow.second) * 1000
