"""Raw-measurement logs for post-processing: RANGECMP (compressed observations) and GPSEPHEM.

These logs pass through the stream decoders as :class:`~drivers.novatel.messages.RawBody` (the
recorder keeps them byte-exact and the live path never needs them); this module decodes them on
demand, for post-processing and checks:

- :func:`decode_rangecmp` — a RANGECMP body (binary, or ASCII with each 24-byte record as 48
  hex digits) into :class:`RangeCmp` records with the bit fields of the OEM7 reference, the ADR
  roll-over resolved as the reference prescribes (``MAX_VALUE`` = 8388608 cycles);
- :func:`decode_gpsephem` / :func:`encode_gpsephem` — GPSEPHEM (7), the decoded GPS broadcast
  ephemeris, through the same declarative layout machinery as the typed logs (:data:`GPSEPHEM_FIELDS`);
- :func:`decode_gloephemeris` / :func:`encode_gloephemeris` — GLOEPHEMERIS (723), the decoded GLONASS
  broadcast ephemeris (PZ-90 state vector at tb, lunisolar acceleration, τn, γn; :data:`GLOEPHEMERIS_FIELDS`).

RANGECMP's GLONASS records (system 1 in the channel tracking status) carry the slot + 37 as PRN and
the frequency channel + 7; their carrier phase is in cycles of 1602 + k·0.5625 MHz (L1) and
1246 + k·0.4375 MHz (L2).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, cast

from drivers.novatel.enums import _OpenIntEnum
from drivers.novatel.layouts import BodyCodec, FieldSpec, Kind, split_ascii_fields
from drivers.novatel.messages import BodyFormat, RawBody
from vsccore.errors import DecodeError, EncodeError

__all__ = [
    "GLOEPHEMERIS_FIELDS",
    "GPSEPHEM_FIELDS",
    "GloEphemeris",
    "GloSatType",
    "GpsEphem",
    "RangeCmp",
    "RangeCmpRecord",
    "SatSystem",
    "decode_gloephemeris",
    "decode_gpsephem",
    "decode_rangecmp",
    "encode_gloephemeris",
    "encode_gpsephem",
    "gloephemeris_codec",
    "glonass_l1_hz",
    "glonass_l2_hz",
    "gpsephem_codec",
    "signal_wavelength_m",
]

#: RANGECMP record size (bytes).
RECORD_LEN = 24
#: ADR roll-over unit of the compressed log (cycles), from the OEM7 reference.
ADR_MAX_VALUE = 8388608.0
#: Pseudorange standard deviation (m) by the 4-bit index of a RANGECMP record.
PSR_STD_M = (0.050, 0.075, 0.113, 0.169, 0.253, 0.380, 0.570, 0.854, 1.281, 2.375, 4.750, 9.500, 19.000,
             38.000, 76.000, 152.000)
#: NovAtel GLONASS PRNs in range logs are slot + 37.
GLONASS_PRN_OFFSET = 37

_C = 299_792_458.0


class SatSystem(_OpenIntEnum):
    """Satellite system of a tracking channel (channel tracking status bits 16-18)."""

    GPS = 0
    GLONASS = 1
    SBAS = 2
    GALILEO = 3
    BEIDOU = 4
    QZSS = 5
    NAVIC = 6
    OTHER = 7


#: Carrier frequency (Hz) by (system, signal type) for the signals whose wavelength is fixed;
#: GLONASS depends on the frequency channel (see :meth:`RangeCmpRecord.wavelength_m`).
_GPS_FREQ_HZ = {0: 1575.42e6, 5: 1227.60e6, 9: 1227.60e6, 14: 1176.45e6, 16: 1575.42e6, 17: 1227.60e6}


@dataclass(frozen=True, slots=True)
class RangeCmpRecord:
    """One compressed observation (one signal of one satellite) of RANGECMP.

    ``adr_cycles`` is the accumulated Doppler range as the receiver reports it (opposite sign to
    the RINEX carrier phase) after roll-over correction; ``adr_raw_cycles`` is the wire value.
    """

    tracking_status: int
    doppler_hz: float
    pseudorange_m: float
    adr_raw_cycles: float
    adr_cycles: float
    psr_std_m: float
    adr_std_cycles: float
    prn: int
    lock_time_s: float
    cn0_dbhz: int
    glonass_fcn: int

    @property
    def tracking_state(self) -> int:
        return self.tracking_status & 0x1F

    @property
    def channel(self) -> int:
        return (self.tracking_status >> 5) & 0x1F

    @property
    def phase_locked(self) -> bool:
        return bool(self.tracking_status >> 10 & 1)

    @property
    def parity_known(self) -> bool:
        return bool(self.tracking_status >> 11 & 1)

    @property
    def code_locked(self) -> bool:
        return bool(self.tracking_status >> 12 & 1)

    @property
    def system(self) -> SatSystem:
        return SatSystem((self.tracking_status >> 16) & 0x7)

    @property
    def signal_type(self) -> int:
        return (self.tracking_status >> 21) & 0x1F

    @property
    def primary_l1(self) -> bool:
        return bool(self.tracking_status >> 27 & 1)

    @property
    def carrier_phase_valid(self) -> bool:
        return bool(self.tracking_status >> 28 & 1)

    @property
    def wavelength_m(self) -> float | None:
        """Carrier wavelength of the signal (GLONASS: of its frequency channel); None for a signal whose
        frequency this decoder does not know."""
        return signal_wavelength_m(self.tracking_status, self.glonass_fcn)


@dataclass(frozen=True, slots=True)
class RangeCmp:
    """RANGECMP (140): compressed range measurements of every tracked signal."""

    MESSAGE_NAME: ClassVar[str] = "RANGECMP"
    MESSAGE_ID: ClassVar[int] = 140

    records: tuple[RangeCmpRecord, ...]


def glonass_l1_hz(fcn: int) -> float:
    """GLONASS L1 (G1) FDMA carrier of frequency channel ``fcn`` (−7..+6): 1602 + k·0.5625 MHz."""
    return 1602.0e6 + fcn * 0.5625e6


def glonass_l2_hz(fcn: int) -> float:
    """GLONASS L2 (G2) FDMA carrier of frequency channel ``fcn`` (−7..+6): 1246 + k·0.4375 MHz."""
    return 1246.0e6 + fcn * 0.4375e6


def signal_wavelength_m(status: int, glonass_fcn: int) -> float | None:
    """Carrier wavelength of the signal a channel tracking status names (system bits 16-18, signal type
    bits 21-25; GLONASS: of frequency channel ``glonass_fcn`` − 7), None where this decoder does not know it."""
    system = (status >> 16) & 0x7
    signal = (status >> 21) & 0x1F
    if system == SatSystem.GLONASS:
        k = glonass_fcn - 7
        if signal == 0:
            return _C / glonass_l1_hz(k)
        if signal in (1, 5):
            return _C / glonass_l2_hz(k)
        return None
    freq = _GPS_FREQ_HZ.get(signal) if system in (SatSystem.GPS, SatSystem.QZSS, SatSystem.SBAS) else None
    return None if freq is None else _C / freq


def _signed(value: int, bits: int) -> int:
    return value - (1 << bits) if value >> (bits - 1) else value


def _decode_record(raw: bytes, where: str) -> RangeCmpRecord:
    if len(raw) != RECORD_LEN:
        raise DecodeError(f"NovAtel RANGECMP {where}: record of {len(raw)} bytes, expected {RECORD_LEN}")
    v = int.from_bytes(raw, "little")
    status = v & 0xFFFFFFFF
    doppler = _signed((v >> 32) & 0xFFFFFFF, 28) / 256.0
    psr = ((v >> 60) & 0xFFFFFFFFF) / 128.0
    adr_raw = _signed((v >> 96) & 0xFFFFFFFF, 32) / 256.0
    psr_std = PSR_STD_M[(v >> 128) & 0xF]
    adr_std = (((v >> 132) & 0xF) + 1) / 512.0
    prn = (v >> 136) & 0xFF
    lock = ((v >> 144) & 0x1FFFFF) / 32.0
    cn0 = ((v >> 165) & 0x1F) + 20
    fcn = (v >> 170) & 0x3F
    adr = adr_raw
    lam = signal_wavelength_m(status, fcn)
    if lam is not None:
        # The 32-bit ADR wraps; the pseudorange tells which wrap (OEM7 reference, RANGECMP).
        rolls = (psr / lam + adr_raw) / ADR_MAX_VALUE
        rolls_int = int(rolls - 0.5) if rolls <= 0 else int(rolls + 0.5)
        adr = adr_raw - ADR_MAX_VALUE * rolls_int
    return RangeCmpRecord(status, doppler, psr, adr_raw, adr, psr_std, adr_std, prn, lock, cn0, fcn)


def decode_rangecmp(body: RawBody | bytes, fmt: BodyFormat = BodyFormat.BINARY) -> RangeCmp:
    """RANGECMP body (binary bytes, or the ASCII text between ``;`` and ``*``) into records.

    Raises:
        DecodeError: the count does not match the records carried, or a record is malformed.
    """
    if isinstance(body, RawBody):
        data, fmt = body.data, body.fmt
    else:
        data = body
    if fmt is BodyFormat.BINARY:
        if len(data) < 4:
            raise DecodeError(f"NovAtel RANGECMP binary body has {len(data)} bytes, needs at least 4")
        (count,) = struct.unpack_from("<I", data)
        if len(data) != 4 + RECORD_LEN * count:
            raise DecodeError(
                f"NovAtel RANGECMP binary body of {len(data)} bytes cannot hold exactly {count} records"
            )
        raws = [data[4 + i * RECORD_LEN : 4 + (i + 1) * RECORD_LEN] for i in range(count)]
    else:
        text = data.decode("latin-1")
        tokens = [t for t in (text.split(",") if fmt is BodyFormat.ASCII else text.split()) if t.strip()]
        try:
            count = int(tokens[0])
            raws = [bytes.fromhex(t) for t in tokens[1:]]
        except (IndexError, ValueError) as exc:
            raise DecodeError(f"NovAtel RANGECMP ASCII body does not parse: {exc}") from exc
        if len(raws) != count:
            raise DecodeError(f"NovAtel RANGECMP ASCII body says {count} records but carries {len(raws)}")
    return RangeCmp(tuple(_decode_record(r, f"record {i + 1}") for i, r in enumerate(raws)))


# --- GPSEPHEM --------------------------------------------------------------------------------


class Bool(_OpenIntEnum):
    """NovAtel BOOL (4 bytes in binary, TRUE/FALSE in ASCII)."""

    FALSE = 0
    TRUE = 1


@dataclass(frozen=True, slots=True)
class GpsEphem:
    """GPSEPHEM (7): decoded GPS broadcast ephemeris (IS-GPS-200 parameters, SI and radians).

    Times of week in seconds; ``a_m`` is the semi-major axis; angles in radians; ``ura_var_m2``
    the user range accuracy variance.
    """

    MESSAGE_NAME: ClassVar[str] = "GPSEPHEM"
    MESSAGE_ID: ClassVar[int] = 7

    prn: int
    tow_s: float
    health: int
    iode1: int
    iode2: int
    week: int
    z_week: int
    toe_s: float
    a_m: float
    delta_n_rad_s: float
    m0_rad: float
    ecc: float
    omega_rad: float
    cuc_rad: float
    cus_rad: float
    crc_m: float
    crs_m: float
    cic_rad: float
    cis_rad: float
    i0_rad: float
    idot_rad_s: float
    omega0_rad: float
    omega_dot_rad_s: float
    iodc: int
    toc_s: float
    tgd_s: float
    af0_s: float
    af1_s_s: float
    af2_s_s2: float
    anti_spoofing: Bool
    n_rad_s: float
    ura_var_m2: float


def _d(name: str, fmt: str = ".12e") -> FieldSpec:
    return FieldSpec(name, "d", Kind.FLOAT, fmt)


def _u(name: str) -> FieldSpec:
    return FieldSpec(name, "I", Kind.INT)


#: GPSEPHEM body in wire order (OEM7 reference; 224 bytes).
GPSEPHEM_FIELDS: tuple[FieldSpec, ...] = (
    _u("prn"),
    _d("tow_s", ".1f"),
    _u("health"),
    _u("iode1"),
    _u("iode2"),
    _u("week"),
    _u("z_week"),
    _d("toe_s", ".1f"),
    *(_d(n) for n in ("a_m", "delta_n_rad_s", "m0_rad", "ecc", "omega_rad", "cuc_rad", "cus_rad", "crc_m",
                      "crs_m", "cic_rad", "cis_rad", "i0_rad", "idot_rad_s", "omega0_rad", "omega_dot_rad_s")),
    _u("iodc"),
    _d("toc_s", ".1f"),
    *(_d(n) for n in ("tgd_s", "af0_s", "af1_s_s", "af2_s_s2")),
    FieldSpec("anti_spoofing", "I", Kind.ENUM, enum=Bool),
    _d("n_rad_s"),
    _d("ura_var_m2"),
)

_GPSEPHEM = BodyCodec(cast(Any, GpsEphem), GPSEPHEM_FIELDS)


def gpsephem_codec() -> BodyCodec:
    """The declarative body codec of GPSEPHEM."""
    return _GPSEPHEM


def decode_gpsephem(body: RawBody | bytes, fmt: BodyFormat = BodyFormat.BINARY) -> GpsEphem:
    """GPSEPHEM body (binary bytes or the ASCII text between ``;`` and ``*``).

    Raises:
        DecodeError: the body is too short or a field does not parse (names the field).
    """
    if isinstance(body, RawBody):
        data, fmt = body.data, body.fmt
    else:
        data = body
    if fmt is BodyFormat.BINARY:
        return cast(GpsEphem, _GPSEPHEM.decode_binary(data))
    text = data.decode("latin-1")
    tokens: Sequence[str] = split_ascii_fields(text) if fmt is BodyFormat.ASCII else text.split()
    return cast(GpsEphem, _GPSEPHEM.decode_ascii([t.strip() for t in tokens]))


def encode_gpsephem(eph: GpsEphem, fmt: BodyFormat = BodyFormat.BINARY) -> RawBody:
    """GPSEPHEM body as a :class:`RawBody` ready for the frame encoders.

    Raises:
        EncodeError: a field does not fit its wire type.
    """
    if fmt is BodyFormat.BINARY:
        return RawBody(_GPSEPHEM.encode_binary(eph), fmt)
    if fmt is BodyFormat.ASCII:
        return RawBody(",".join(_GPSEPHEM.format_tokens(eph)).encode("ascii"), fmt)
    raise EncodeError(f"NovAtel GPSEPHEM: cannot encode a {fmt.value} body")


# --- GLOEPHEMERIS ----------------------------------------------------------------------------


class GloSatType(_OpenIntEnum):
    """GLONASS satellite type of GLOEPHEMERIS."""

    GLO_SAT = 0
    GLO_SAT_M = 1
    GLO_SAT_K = 2


@dataclass(frozen=True, slots=True)
class GloEphemeris:
    """GLOEPHEMERIS (723): decoded GLONASS broadcast ephemeris (ICD GLONASS 5.1 immediate data, SI units).

    The orbit is the PZ-90 state at the reference time tb (``ephem_week`` / ``ephem_time_ms``, in GPS
    time) that a receiver integrates with the equations of motion of ICD A.3.1.2; the satellite
    clock is t_sat − t_GLONASS = −τn + γn·(t − tb). ``time_offset_s`` is GLONASS minus GPS time in
    whole seconds (3 h minus the leap seconds); ``tk_s`` the frame start in seconds of the GLONASS
    day; ``issue`` the 15-minute interval number of tb in the day.
    """

    MESSAGE_NAME: ClassVar[str] = "GLOEPHEMERIS"
    MESSAGE_ID: ClassVar[int] = 723

    sloto: int
    freqo: int
    sat_type: int
    false_iod: int
    ephem_week: int
    ephem_time_ms: int
    time_offset_s: int
    nt_day: int
    reserved1: int
    reserved2: int
    issue: int
    health: int
    pos_x_m: float
    pos_y_m: float
    pos_z_m: float
    vel_x_mps: float
    vel_y_mps: float
    vel_z_mps: float
    ls_acc_x_mps2: float
    ls_acc_y_mps2: float
    ls_acc_z_mps2: float
    tau_n_s: float
    delta_tau_n_s: float
    gamma_n: float
    tk_s: int
    p: int
    ft: int
    age_days: int
    flags: int

    @property
    def slot(self) -> int:
        """Orbital slot 1..24 (``sloto`` − 37)."""
        return self.sloto - GLONASS_PRN_OFFSET

    @property
    def satellite_type(self) -> GloSatType:
        return GloSatType(self.sat_type)

    @property
    def fcn(self) -> int:
        """Frequency channel number −7..+6 (``freqo`` − 7)."""
        return self.freqo - 7

    @property
    def tb_gps_s(self) -> float:
        """Reference time tb in GPS seconds since the GPS epoch."""
        return self.ephem_week * 604800.0 + self.ephem_time_ms / 1000.0

    @property
    def healthy(self) -> bool:
        """Broadcast health 0-3 is good, 4-15 bad (OEM7 reference)."""
        return self.health < 4

    def position_m(self) -> tuple[float, float, float]:
        return (self.pos_x_m, self.pos_y_m, self.pos_z_m)

    def velocity_mps(self) -> tuple[float, float, float]:
        return (self.vel_x_mps, self.vel_y_mps, self.vel_z_mps)

    def lunisolar_mps2(self) -> tuple[float, float, float]:
        return (self.ls_acc_x_mps2, self.ls_acc_y_mps2, self.ls_acc_z_mps2)


def _h(name: str) -> FieldSpec:
    return FieldSpec(name, "H", Kind.INT)


def _b(name: str) -> FieldSpec:
    return FieldSpec(name, "B", Kind.INT)


#: GLOEPHEMERIS body in wire order (OEM7 reference; 144 bytes). Doubles print as the shortest
#: round-tripping decimal, so the ASCII form carries the binary values exactly.
GLOEPHEMERIS_FIELDS: tuple[FieldSpec, ...] = (
    _h("sloto"),
    _h("freqo"),
    _b("sat_type"),  # GloSatType; a number in ASCII too
    _b("false_iod"),
    _h("ephem_week"),
    _u("ephem_time_ms"),
    _u("time_offset_s"),
    _h("nt_day"),
    _b("reserved1"),
    _b("reserved2"),
    _u("issue"),
    _u("health"),
    *(_d(n, "") for n in ("pos_x_m", "pos_y_m", "pos_z_m", "vel_x_mps", "vel_y_mps", "vel_z_mps",
                          "ls_acc_x_mps2", "ls_acc_y_mps2", "ls_acc_z_mps2", "tau_n_s", "delta_tau_n_s", "gamma_n")),
    _u("tk_s"),
    _u("p"),
    _u("ft"),
    _u("age_days"),
    _u("flags"),
)
GLOEPHEMERIS_LEN = 144

_GLOEPHEMERIS = BodyCodec(cast(Any, GloEphemeris), GLOEPHEMERIS_FIELDS)


def gloephemeris_codec() -> BodyCodec:
    """The declarative body codec of GLOEPHEMERIS (without the slot and channel checks of
    :func:`decode_gloephemeris`)."""
    return _GLOEPHEMERIS


def decode_gloephemeris(body: RawBody | bytes, fmt: BodyFormat = BodyFormat.BINARY) -> GloEphemeris:
    """GLOEPHEMERIS body (binary bytes or the ASCII text between ``;`` and ``*``).

    Raises:
        DecodeError: the body is too short, a field does not parse (names the field), or the slot /
            frequency channel is out of range.
    """
    if isinstance(body, RawBody):
        data, fmt = body.data, body.fmt
    else:
        data = body
    if fmt is BodyFormat.BINARY:
        eph = cast(GloEphemeris, _GLOEPHEMERIS.decode_binary(data))
    else:
        text = data.decode("latin-1")
        tokens: Sequence[str] = split_ascii_fields(text) if fmt is BodyFormat.ASCII else text.split()
        eph = cast(GloEphemeris, _GLOEPHEMERIS.decode_ascii([t.strip() for t in tokens]))
    if not 1 <= eph.slot <= 32:
        raise DecodeError(f"NovAtel GLOEPHEMERIS: slot offset {eph.sloto} is not a GLONASS slot (38..69: slot + 37)")
    if not 0 <= eph.freqo <= 20:
        raise DecodeError(f"NovAtel GLOEPHEMERIS slot {eph.slot}: frequency offset {eph.freqo} out of range "
                          "(0..20: channel + 7)")
    return eph


def encode_gloephemeris(eph: GloEphemeris, fmt: BodyFormat = BodyFormat.BINARY) -> RawBody:
    """GLOEPHEMERIS body as a :class:`RawBody` ready for the frame encoders.

    Raises:
        EncodeError: a field does not fit its wire type.
    """
    if fmt is BodyFormat.BINARY:
        return RawBody(_GLOEPHEMERIS.encode_binary(eph), fmt)
    if fmt is BodyFormat.ASCII:
        return RawBody(",".join(_GLOEPHEMERIS.format_tokens(eph)).encode("ascii"), fmt)
    raise EncodeError(f"NovAtel GLOEPHEMERIS: cannot encode a {fmt.value} body")
