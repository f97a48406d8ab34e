"""Bodies of the logs the codec keeps raw (RANGECMP, RXSTATUS) and the NMEA GPGGA sentence.

RANGECMP: a ulong observation count, then one 24-byte compressed record per signal, bit fields
little-endian as in the OEM7 reference (tracking status; Doppler 28 bits at 1/256 Hz; pseudorange
36 bits at 1/128 m; ADR 32 bits at 1/256 cycles; σ indices; PRN/slot; lock time 21 bits at
1/32 s; C/N0 − 20 dB-Hz in 5 bits; GLONASS frequency + 7 in 6 bits). The ASCII form writes each
record as 48 hex digits.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

from drivers.novatel.crc import xor_checksum
from sim_devices.gnss.constellation import GnssSystem
from sim_devices.gnss.observations import Band, SignalObservation

__all__ = ["gpgga_sentence", "rangecmp_ascii", "rangecmp_binary", "rxstatus_ascii", "rxstatus_binary"]

#: NovAtel GLONASS PRNs are slot + 37 (38..61).
GLONASS_PRN_OFFSET = 37


def _tracking_status(obs: SignalObservation, channel: int) -> int:
    system = 0 if obs.sat.system is GnssSystem.GPS else 1
    if obs.sat.system is GnssSystem.GPS:
        signal = 0 if obs.band is Band.L1 else 9  # L1 C/A, L2 P(Y) semi-codeless
    else:
        signal = 0 if obs.band is Band.L1 else 1  # L1 C/A, L2 C/A
    status = 4  # phase lock loop
    status |= (channel & 0x1F) << 5
    status |= 1 << 10  # phase locked
    status |= 1 << 11  # parity known
    status |= 1 << 12  # code locked
    status |= 1 << 13  # correlator: standard
    status |= system << 16
    status |= 1 << 20  # grouped with the other signal of this satellite
    status |= signal << 21
    if obs.band is Band.L1:
        status |= 1 << 27  # primary L1
    status |= 1 << 28  # carrier phase measurement
    return status


def _record(obs: SignalObservation, channel: int) -> bytes:
    doppler = round(obs.doppler_hz * 256) & ((1 << 28) - 1)
    psr = round(obs.pseudorange_m * 128) & ((1 << 36) - 1)
    adr = round(-obs.carrier_cycles * 256)
    adr = ((adr + (1 << 31)) % (1 << 32)) - (1 << 31)  # rolls over like the receiver's
    prn = obs.sat.prn + (GLONASS_PRN_OFFSET if obs.sat.system is GnssSystem.GLONASS else 0)
    lock = min(round(obs.lock_time_s * 32), (1 << 21) - 1)
    cno = min(max(round(obs.cnr_dbhz) - 20, 0), 31)
    glo = (obs.sat.fcn + 7) if obs.sat.system is GnssSystem.GLONASS else 0
    v = _tracking_status(obs, channel)
    v |= doppler << 32
    v |= psr << 60
    v |= (adr & 0xFFFFFFFF) << 96
    v |= 5 << 128  # pseudorange σ index (≈ 0.4-0.5 m)
    v |= 3 << 132  # ADR σ: (3 + 1)/512 cycles
    v |= prn << 136
    v |= lock << 144
    v |= cno << 165
    v |= glo << 170
    return v.to_bytes(24, "little")


def rangecmp_binary(observations: Sequence[SignalObservation]) -> bytes:
    """RANGECMP binary body."""
    return struct.pack("<I", len(observations)) + b"".join(
        _record(o, i // 2) for i, o in enumerate(observations)
    )


def rangecmp_ascii(observations: Sequence[SignalObservation]) -> bytes:
    """RANGECMP ASCII body: the count, then each record as hex."""
    parts = [str(len(observations))] + [_record(o, i // 2).hex() for i, o in enumerate(observations)]
    return ",".join(parts).encode("ascii")


def rxstatus_binary(error: int, words: Sequence[int]) -> bytes:
    """RXSTATUS binary body (RXSTATUS): the receiver error word, the number of status codes, then per code
    (receiver status, auxiliary 1-4) the status word and its priority, event-set and event-clear masks
    (left 0: no event reporting configured)."""
    body = struct.pack("<II", error, len(words))
    for w in words:
        body += struct.pack("<IIII", w, 0, 0, 0)
    return body


def rxstatus_ascii(error: int, words: Sequence[int]) -> bytes:
    """RXSTATUS ASCII body: the same fields, the words as 8 hex digits."""
    parts = [f"{error:08x}", str(len(words))]
    for w in words:
        parts += [f"{w:08x}", "00000000", "00000000", "00000000"]
    return ",".join(parts).encode("ascii")


def _nmea_angle(value: float, deg_digits: int) -> str:
    a = abs(value)
    d = int(a)
    m = (a - d) * 60.0
    if round(m, 7) >= 60.0:
        d, m = d + 1, 0.0
    return f"{d:0{deg_digits}d}{m:010.7f}"


def gpgga_sentence(
    utc_hms: tuple[int, int, float],
    lat_deg: float,
    lon_deg: float,
    quality: int,
    num_sats: int,
    hdop: float,
    msl_height_m: float,
    undulation_m: float,
    diff_age_s: float | None,
    station_id: str,
) -> bytes:
    """``$GPGGA`` sentence (CR LF ended) as NovAtel writes it."""
    h, m, s = utc_hms
    fields = [
        "GPGGA",
        f"{h:02d}{m:02d}{s:05.2f}",
        _nmea_angle(lat_deg, 2),
        "N" if lat_deg >= 0 else "S",
        _nmea_angle(lon_deg, 3),
        "E" if lon_deg >= 0 else "W",
        str(quality),
        f"{num_sats:02d}",
        f"{hdop:.1f}",
        f"{msl_height_m:.3f}",
        "M",
        f"{undulation_m:.3f}",
        "M",
        "" if diff_age_s is None else f"{diff_age_s:.1f}",
        station_id if diff_age_s is not None else "",
    ]
    text = ",".join(fields)
    return f"${text}*{xor_checksum(text.encode('ascii')):02X}\r\n".encode("ascii")
