"""RANGECMP and GPSEPHEM decoding, checked against a real capture and against NovAtel's EDIE decoder."""

from __future__ import annotations

import math
from dataclasses import fields
from pathlib import Path
from typing import Any

import pytest

from drivers.novatel import Header, TimeStatus, decode_ascii, decode_binary, encode_ascii, encode_binary
from drivers.novatel.messages import BodyFormat, RawBody
from drivers.novatel.rawobs import (
    Bool,
    GpsEphem,
    SatSystem,
    decode_gpsephem,
    decode_rangecmp,
    encode_gpsephem,
)
from sim_devices.gnss.antenna import AntennaState
from sim_devices.gnss.constellation import Constellation
from sim_devices.gnss.observations import ObservationGenerator
from sim_devices.gnss.rawlogs import rangecmp_ascii, rangecmp_binary
from vsccore.errors import DecodeError
from vsccore.gpstime import NS_PER_S, NS_PER_WEEK

oem = pytest.importorskip("novatel_edie.oem")

DATA = Path(__file__).parent / "data"


def _edie_logs(data: bytes, *, decompress: bool) -> list[Any]:
    """Every message EDIE's parser finds in ``data`` (RANGECMP decompressed to RANGE on request)."""
    parser = oem.Parser()
    parser.decompress_range_cmp = decompress
    parser.write(data)
    out = []
    while True:
        try:
            out.append(parser.read())
        except Exception as exc:  # EDIE signals the end of its buffer with an exception
            if type(exc).__name__ == "BufferEmptyException":
                return out
            raise


def _capture() -> tuple[bytes, bytes]:
    lines = [ln.strip().encode("ascii") for ln in (DATA / "rangecmp_oem4_manual.txt").read_text().splitlines()]
    cmp_line, range_line = (ln for ln in lines if ln.startswith(b"#RANGE"))
    return cmp_line + b"\r\n", range_line + b"\r\n"


def _range_rows(range_body: bytes) -> list[list[str]]:
    tokens = range_body.decode().split(",")
    count = int(tokens[0])
    return [tokens[1 + 10 * i : 11 + 10 * i] for i in range(count)]


def test_real_rangecmpa_matches_the_receivers_own_range_log() -> None:
    """A real OEM4 RANGECMPA decodes to the values the receiver printed in RANGEA for the same epoch."""
    cmp_line, range_line = _capture()
    cmp_log = decode_ascii(cmp_line)
    assert isinstance(cmp_log.body, RawBody)
    got = decode_rangecmp(cmp_log.body)
    rows = _range_rows(decode_ascii(range_line).body.data)  # type: ignore[union-attr]
    assert len(got.records) == len(rows) == 12
    for rec, row in zip(got.records, rows, strict=True):
        prn, _, psr, psr_std, adr, adr_std, dop, cn0, lock, status = row
        assert rec.prn == int(prn)
        assert rec.pseudorange_m == pytest.approx(float(psr), abs=1e-3)
        assert rec.psr_std_m == pytest.approx(float(psr_std), abs=1e-3)
        assert rec.adr_cycles == pytest.approx(float(adr), abs=1e-3)  # roll-over resolved
        assert rec.adr_std_cycles == pytest.approx(float(adr_std), abs=1e-3)
        assert rec.doppler_hz == pytest.approx(float(dop), abs=1e-3)
        assert rec.cn0_dbhz == pytest.approx(float(cn0))
        assert rec.lock_time_s == pytest.approx(float(lock), abs=1e-3)
        assert rec.tracking_status == int(status, 16)
        assert rec.system is SatSystem.GPS and rec.phase_locked and rec.code_locked
    assert got.records[0].primary_l1 and not got.records[1].primary_l1
    assert got.records[10].channel == 11


def _compare_with_edie_range(records: Any, edie_obs: list[dict[str, Any]], *, tol: float) -> None:
    assert len(records) == len(edie_obs)
    for rec, ref in zip(records, edie_obs, strict=True):
        assert rec.prn == ref["sv_prn"]
        assert rec.glonass_fcn == ref["sv_freq"]
        assert rec.tracking_status == ref["c_status"]
        assert rec.pseudorange_m == pytest.approx(ref["psr"], abs=tol)
        assert rec.adr_cycles == pytest.approx(ref["adr"], abs=tol)
        assert rec.doppler_hz == pytest.approx(ref["dop"], abs=tol)
        assert rec.psr_std_m == pytest.approx(ref["sd_psr"], abs=1e-3)
        assert rec.adr_std_cycles == pytest.approx(ref["sd_adr"], abs=1e-3)
        assert rec.cn0_dbhz == pytest.approx(ref["C_No"])
        assert rec.lock_time_s == pytest.approx(ref["lock_time"], abs=tol)


def test_real_rangecmpa_agrees_with_edie() -> None:
    cmp_line, _ = _capture()
    (edie,) = _edie_logs(cmp_line, decompress=True)
    ours = decode_rangecmp(decode_ascii(cmp_line).body)  # type: ignore[arg-type]
    _compare_with_edie_range(ours.records, edie.to_dict()["obs"], tol=1e-3)


def _sim_epoch(t_s: float) -> list[Any]:
    gen = ObservationGenerator(Constellation(), seed=3)
    t_ns = 2300 * NS_PER_WEEK + round(t_s * NS_PER_S)
    gen.epoch(AntennaState(48.1, 11.5, 520.0, 0.0, 0.0, 0.0), t_ns - 60 * NS_PER_S)  # locks start earlier
    return gen.epoch(AntennaState(48.1, 11.5, 520.0, 0.0, 0.0, 0.0), t_ns)


@pytest.mark.parametrize("t_s", [345600.0, 86400.0 * 3 + 7201.5])
def test_simulated_rangecmpb_and_a_agree_with_edie(t_s: float) -> None:
    """Both wire forms of a simulated epoch (GPS + GLONASS, L1 + L2) decode like EDIE's decompressor."""
    obs = _sim_epoch(t_s)
    assert {o.sat.system.value for o in obs} == {"GPS", "GLONASS"}
    header = Header("RANGECMP", 140, "COM1", 0, 50.0, TimeStatus.FINESTEERING, 2300, t_s, 0, 0, 0)
    binary = encode_binary(header, RawBody(rangecmp_binary(obs), BodyFormat.BINARY))
    ascii_ = encode_ascii(header, RawBody(rangecmp_ascii(obs), BodyFormat.ASCII))
    (edie_b, edie_a) = _edie_logs(binary + ascii_, decompress=True)
    ours_b = decode_rangecmp(decode_binary(binary).body)  # type: ignore[arg-type]
    ours_a = decode_rangecmp(decode_ascii(ascii_).body)  # type: ignore[arg-type]
    assert ours_a == ours_b
    _compare_with_edie_range(ours_b.records, edie_b.to_dict()["obs"], tol=1e-6)
    _compare_with_edie_range(ours_a.records, edie_a.to_dict()["obs"], tol=2e-3)  # EDIE re-prints in ASCII
    # and the decoded carrier phase is the simulated one (ADR = −phase), to the 1/256-cycle resolution
    for rec, o in zip(ours_b.records, obs, strict=True):
        assert -rec.adr_cycles == pytest.approx(o.carrier_cycles, abs=1 / 512 + 1e-9)
        assert rec.pseudorange_m == pytest.approx(o.pseudorange_m, abs=1 / 256 + 1e-9)


def test_rangecmp_errors_name_the_problem() -> None:
    with pytest.raises(DecodeError, match="cannot hold exactly 2 records"):
        decode_rangecmp(b"\x02\x00\x00\x00" + bytes(24))
    with pytest.raises(DecodeError, match="says 2 records but carries 1"):
        decode_rangecmp(RawBody(b"2," + b"00" * 24, BodyFormat.ASCII))
    with pytest.raises(DecodeError, match="record 1: record of 23 bytes"):
        decode_rangecmp(RawBody(b"1," + b"00" * 23, BodyFormat.ASCII))


def _ephemeris() -> GpsEphem:
    a = 26_559_700.0
    n = math.sqrt(3.986005e14 / a**3)
    return GpsEphem(
        prn=7, tow_s=345600.0, health=0, iode1=12, iode2=12, week=2300, z_week=2300, toe_s=352800.0, a_m=a,
        delta_n_rad_s=4.3e-9, m0_rad=-1.2345678901, ecc=0.0123456789, omega_rad=0.987654321, cuc_rad=1.2e-6,
        cus_rad=-3.4e-6, crc_m=210.5, crs_m=-15.25, cic_rad=7.4e-8, cis_rad=-1.1e-7, i0_rad=0.96, idot_rad_s=2.1e-10,
        omega0_rad=2.5, omega_dot_rad_s=-8.1e-9, iodc=12, toc_s=352800.0, tgd_s=-1.1e-8, af0_s=1.2345e-4,
        af1_s_s=-3.4e-12, af2_s_s2=0.0, anti_spoofing=Bool.TRUE, n_rad_s=n, ura_var_m2=4.0,
    )


_NAMES = tuple(f.name for f in fields(GpsEphem))


def test_gpsephem_binary_and_ascii_agree_with_edie_both_ways() -> None:
    """Our GPSEPHEMB/A frames decode in EDIE to the same values, and EDIE's own re-encoding decodes in ours."""
    eph = _ephemeris()
    header = Header("GPSEPHEM", 7, "COM1", 0, 50.0, TimeStatus.FINESTEERING, 2300, 345600.0, 0, 0, 0)
    body = encode_gpsephem(eph)
    assert len(body.data) == 224
    binary = encode_binary(header, body)
    ascii_ = encode_ascii(header, encode_gpsephem(eph, BodyFormat.ASCII))
    edie_b, edie_a = _edie_logs(binary + ascii_, decompress=False)
    ref = edie_b.to_dict()
    edie_names = ("satellite_id", "tow", "health7", "iode1", "iode2", "wn", "zwn", "toe", "a", "delta_n", "m0",
                  "ecc", "omega", "cuc", "cus", "crc", "crs", "cic", "cis", "i0", "i_dot", "omega0", "omega_dot",
                  "iodc", "toc", "tgd", "af0", "af1", "af2", "anti_spoofing", "n", "eph_var")
    ours = decode_gpsephem(decode_binary(binary).body)  # type: ignore[arg-type]
    assert ours == eph
    for ours_name, edie_name in zip(_NAMES, edie_names, strict=True):
        assert float(getattr(ours, ours_name)) == float(ref[edie_name]), ours_name
    for ours_name, edie_name in zip(_NAMES, edie_names, strict=True):
        assert float(getattr(ours, ours_name)) == pytest.approx(float(edie_a.to_dict()[edie_name]), rel=1e-9)
    # EDIE re-encodes its ASCII parse as binary; our decoder reads that frame
    edie_binary = bytes(edie_a.to_binary().message)
    back = decode_gpsephem(decode_binary(edie_binary).body)  # type: ignore[arg-type]
    for name in _NAMES:
        assert float(getattr(back, name)) == pytest.approx(float(getattr(eph, name)), rel=1e-9), name
    ours_a = decode_gpsephem(decode_ascii(ascii_).body)  # type: ignore[arg-type]
    assert ours_a.anti_spoofing is Bool.TRUE and ours_a.a_m == pytest.approx(eph.a_m, rel=1e-12)


def test_gpsephem_short_body_names_the_log() -> None:
    with pytest.raises(DecodeError, match="GPSEPHEM binary body has 100 bytes"):
        decode_gpsephem(bytes(100))
