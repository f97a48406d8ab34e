"""GLOEPHEMERIS (723) decoding and encoding, checked against NovAtel's EDIE both ways, and GLONASS
records of RANGECMP (slot + 37, FDMA wavelengths)."""

from __future__ import annotations

from dataclasses import fields, replace
from typing import Any

import pytest

from drivers.novatel import Header, TimeStatus, decode_ascii, decode_binary, encode_ascii, encode_binary
from drivers.novatel.messages import BodyFormat, RawBody
from drivers.novatel.rawobs import (
    GloEphemeris,
    GloSatType,
    SatSystem,
    decode_gloephemeris,
    decode_rangecmp,
    encode_gloephemeris,
    glonass_l1_hz,
    glonass_l2_hz,
)
from vsccore.errors import DecodeError

oem = pytest.importorskip("novatel_edie.oem")

_C = 299_792_458.0


def _edie_logs(data: bytes) -> list[Any]:
    parser = oem.Parser()
    parser.write(data)
    out = []
    while True:
        try:
            out.append(parser.read())
        except Exception as exc:  # EDIE signals the end of its buffer with an exception
            if type(exc).__name__ == "BufferEmptyException":
                return out
            raise


def _ephemeris() -> GloEphemeris:
    """A set with the magnitudes of a real broadcast (slot 14, channel −7, tb = 10:15 Moscow time)."""
    return GloEphemeris(
        sloto=14 + 37, freqo=0, sat_type=GloSatType.GLO_SAT_M, false_iod=80, ephem_week=2300,
        ephem_time_ms=(86400 * 3 + 7 * 3600 + 900 + 18) * 1000, time_offset_s=10782, nt_day=573, reserved1=0,
        reserved2=0, issue=41, health=0, pos_x_m=-23_114_356.201171875, pos_y_m=3_366_334.9609375,
        pos_z_m=3_757_992.96875, vel_x_mps=-101.90830230712891, vel_y_mps=1686.1824035644531,
        vel_z_mps=-3402.6954650878906, ls_acc_x_mps2=1.862645149230957e-06, ls_acc_y_mps2=-9.313225746154785e-07,
        ls_acc_z_mps2=0.0, tau_n_s=-6.6227652132511139e-05, delta_tau_n_s=5.587935448e-09,
        gamma_n=9.094947017729282e-13, tk_s=36870, p=3, ft=0, age_days=0, flags=12,
    )


_NAMES = tuple(f.name for f in fields(GloEphemeris))
_EDIE_NAMES = ("sloto", "freqo", "sat_type", "false_iod", "ephem_week", "ephem_time", "time_offset", "nt",
               "GLOEPHEMERIS_reserved", "GLOEPHEMERIS_reserved_1", "issue", "broadcast_health", "pos_x", "pos_y",
               "pos_z", "vel_x", "vel_y", "vel_z", "ls_acc_x", "ls_acc_y", "ls_acc_z", "tau", "delta_tau", "gamma",
               "tk", "p", "ft", "age", "flags")


def _header() -> Header:
    return Header("GLOEPHEMERIS", 723, "COM1", 0, 50.0, TimeStatus.SATTIME, 2300, 266418.0, 0, 0, 0)


def test_gloephemeris_binary_and_ascii_agree_with_edie_both_ways() -> None:
    """Our GLOEPHEMERISB/A frames decode in EDIE to the same values, EDIE's re-encodings decode in ours."""
    eph = _ephemeris()
    body = encode_gloephemeris(eph)
    assert len(body.data) == 144
    binary = encode_binary(_header(), body)
    ascii_ = encode_ascii(_header(), encode_gloephemeris(eph, BodyFormat.ASCII))
    edie_b, edie_a = _edie_logs(binary + ascii_)
    assert edie_b.header.message_id == edie_a.header.message_id == 723
    ref_b, ref_a = edie_b.to_dict(), edie_a.to_dict()
    for ours_name, edie_name in zip(_NAMES, _EDIE_NAMES, strict=True):
        assert float(getattr(eph, ours_name)) == float(ref_b[edie_name]), ours_name
        assert float(getattr(eph, ours_name)) == pytest.approx(float(ref_a[edie_name]), rel=1e-12), ours_name
    assert decode_gloephemeris(decode_binary(binary).body) == eph  # type: ignore[arg-type]
    assert decode_gloephemeris(decode_ascii(ascii_).body) == eph  # type: ignore[arg-type]  # exact in ASCII
    # EDIE's own encodings (binary from its ASCII parse, ASCII from its binary parse) decode in ours
    from_edie_b = decode_gloephemeris(decode_binary(bytes(edie_a.to_binary().message)).body)  # type: ignore[arg-type]
    from_edie_a = decode_gloephemeris(decode_ascii(bytes(edie_b.to_ascii().message)).body)  # type: ignore[arg-type]
    for back in (from_edie_b, from_edie_a):
        for name in _NAMES:
            assert float(getattr(back, name)) == pytest.approx(float(getattr(eph, name)), rel=1e-9), name


def test_gloephemeris_units_and_derived_values() -> None:
    eph = _ephemeris()
    assert eph.slot == 14 and eph.fcn == -7 and eph.satellite_type is GloSatType.GLO_SAT_M and eph.healthy
    assert eph.tb_gps_s == 2300 * 604800 + 86400 * 3 + 7 * 3600 + 900 + 18
    # tb in GLONASS time of day = GPS time of day + time offset: 10:15:00 Moscow time, the 41st 15-min interval
    assert (eph.ephem_time_ms // 1000 + eph.time_offset_s) % 86400 == 10 * 3600 + 15 * 60 == eph.issue * 900
    assert eph.position_m() == (eph.pos_x_m, eph.pos_y_m, eph.pos_z_m)
    assert not replace(eph, health=4).healthy


def test_gloephemeris_errors_name_the_log_and_field() -> None:
    with pytest.raises(DecodeError, match="GLOEPHEMERIS binary body has 100 bytes"):
        decode_gloephemeris(bytes(100))
    bad_slot = encode_gloephemeris(replace(_ephemeris(), sloto=3))
    with pytest.raises(DecodeError, match="slot offset 3 is not a GLONASS slot"):
        decode_gloephemeris(bad_slot)
    bad_freq = encode_gloephemeris(replace(_ephemeris(), freqo=21), BodyFormat.ASCII)
    with pytest.raises(DecodeError, match="slot 14: frequency offset 21 out of range"):
        decode_gloephemeris(bad_freq)
    text = encode_gloephemeris(_ephemeris(), BodyFormat.ASCII).data.split(b",")
    text[12] = b"x12"
    with pytest.raises(DecodeError, match=r"field 13 \(pos_x_m\)"):
        decode_gloephemeris(RawBody(b",".join(text), BodyFormat.ASCII))


def _glonass_record(fcn: int, l2: bool, psr_m: float, slot: int) -> bytes:
    """One RANGECMP record of a GLONASS signal (OEM7 bit layout) whose phase is the pseudorange in cycles."""
    lam = _C / (glonass_l2_hz(fcn) if l2 else glonass_l1_hz(fcn))
    status = 4 | 1 << 10 | 1 << 11 | 1 << 12 | 1 << 16 | ((1 if l2 else 0) << 21) | 1 << 28
    adr = round(-psr_m / lam * 256)
    adr = ((adr + (1 << 31)) % (1 << 32)) - (1 << 31)
    v = status | round(psr_m * 128) << 60 | (adr & 0xFFFFFFFF) << 96 | (slot + 37) << 136 | (fcn + 7) << 170
    return v.to_bytes(24, "little")


@pytest.mark.parametrize("fcn", [-7, 0, 6])
def test_rangecmp_glonass_records_use_the_fdma_wavelength_of_their_channel(fcn: int) -> None:
    """A GLONASS record names system 1, slot + 37 and channel + 7; its rolled-over ADR is resolved with
    1602 + k·0.5625 MHz (L1) and 1246 + k·0.4375 MHz (L2), and EDIE's decompressor agrees."""
    psr = 21_345_678.125
    body = b"\x02\x00\x00\x00" + _glonass_record(fcn, False, psr, 9) + _glonass_record(fcn, True, psr, 9)
    l1, l2 = decode_rangecmp(body).records
    assert l1.system is l2.system is SatSystem.GLONASS and l1.prn == 46 and l1.glonass_fcn == fcn + 7
    assert l1.wavelength_m == pytest.approx(_C / (1602.0e6 + fcn * 0.5625e6), rel=1e-15)
    assert l2.wavelength_m == pytest.approx(_C / (1246.0e6 + fcn * 0.4375e6), rel=1e-15)
    for rec in (l1, l2):
        assert rec.wavelength_m is not None
        assert -rec.adr_cycles * rec.wavelength_m == pytest.approx(psr, abs=0.01)  # roll-over resolved
        assert rec.adr_cycles != rec.adr_raw_cycles
    header = Header("RANGECMP", 140, "COM1", 0, 50.0, TimeStatus.FINESTEERING, 2300, 266418.0, 0, 0, 0)
    parser = oem.Parser()
    parser.decompress_range_cmp = True
    parser.write(encode_binary(header, RawBody(body, BodyFormat.BINARY)))
    edie = parser.read().to_dict()["obs"]
    assert [o["adr"] for o in edie] == pytest.approx([l1.adr_cycles, l2.adr_cycles], abs=1e-6)
    assert [o["sv_freq"] for o in edie] == [fcn + 7, fcn + 7]
