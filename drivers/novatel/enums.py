"""Enumerations of the NovAtel OEM4/OEMV/OEM6/OEM7 log family, and the port-name table.

Values follow the NovAtel OEM7 Commands and Logs reference (OEMV values that OEM7 marks as
reserved are kept, so older captures still decode). A value a receiver sends that is not in a
table does not break decoding: it becomes a pseudo-member named ``UNKNOWN_<value>`` that
compares equal to its integer and encodes back to the same value.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Any, Self


class _OpenIntEnum(IntEnum):
    """IntEnum that accepts values missing from the table (newer firmware) as pseudo-members."""

    @classmethod
    def _missing_(cls, value: object) -> Self | None:
        if isinstance(value, int) and not isinstance(value, bool):
            member = int.__new__(cls, value)
            member._name_ = f"UNKNOWN_{value}"
            member._value_ = value
            return member
        return None

    @classmethod
    def from_token(cls, token: str) -> Self:
        """Member from an ASCII token: its name, or a decimal value (some firmware prints numbers).

        Raises:
            KeyError: the token is neither a known name nor a decimal integer.
        """
        member = cls._member_map_.get(token)
        if member is not None:
            return member  # type: ignore[return-value]
        if token.startswith("UNKNOWN_"):
            token = token[8:]
        if token.isdigit():
            return cls(int(token))
        raise KeyError(token)


class SolutionStatus(_OpenIntEnum):
    """Solution status (BESTPOS, BESTVEL, HEADING, …)."""

    SOL_COMPUTED = 0
    INSUFFICIENT_OBS = 1
    NO_CONVERGENCE = 2
    SINGULARITY = 3
    COV_TRACE = 4
    TEST_DIST = 5
    COLD_START = 6
    V_H_LIMIT = 7
    VARIANCE = 8
    RESIDUALS = 9
    DELTA_POS = 10  # OEMV; reserved on OEM7
    NEGATIVE_VAR = 11  # OEMV; reserved on OEM7
    INTEGRITY_WARNING = 13
    INS_INACTIVE = 14  # OEMV SPAN; reserved on OEM7
    INS_ALIGNING = 15  # OEMV SPAN
    INS_BAD = 16  # OEMV SPAN
    IMU_UNPLUGGED = 17  # OEMV SPAN
    PENDING = 18
    INVALID_FIX = 19
    UNAUTHORIZED = 20
    ANTENNA_WARNING = 21  # OEMV
    INVALID_RATE = 22


class PositionType(_OpenIntEnum):
    """Position or velocity type (one table for both, as in the NovAtel reference)."""

    NONE = 0
    FIXEDPOS = 1
    FIXEDHEIGHT = 2
    FLOATCONV = 4  # OEMV
    WIDELANE = 5  # OEMV
    NARROWLANE = 6  # OEMV
    DOPPLER_VELOCITY = 8
    SINGLE = 16
    PSRDIFF = 17
    WAAS = 18
    PROPAGATED = 19
    OMNISTAR = 20  # OEMV
    L1_FLOAT = 32
    IONOFREE_FLOAT = 33
    NARROW_FLOAT = 34
    L1_INT = 48
    WIDE_INT = 49
    NARROW_INT = 50
    RTK_DIRECT_INS = 51
    INS_SBAS = 52
    INS_PSRSP = 53
    INS_PSRDIFF = 54
    INS_RTKFLOAT = 55
    INS_RTKFIXED = 56
    INS_OMNISTAR = 57  # OEMV
    INS_OMNISTAR_HP = 58  # OEMV
    INS_OMNISTAR_XP = 59  # OEMV
    OMNISTAR_HP = 64
    OMNISTAR_XP = 65
    CDGPS = 66  # OEMV
    EXT_CONSTRAINED = 67
    PPP_CONVERGING = 68
    PPP = 69
    OPERATIONAL = 70
    WARNING = 71
    OUT_OF_BOUNDS = 72
    INS_PPP_CONVERGING = 73
    INS_PPP = 74
    PPP_BASIC_CONVERGING = 77
    PPP_BASIC = 78
    INS_PPP_BASIC_CONVERGING = 79
    INS_PPP_BASIC = 80


#: Velocity type uses the position-type table.
VelocityType = PositionType


class TimeStatus(_OpenIntEnum):
    """GPS reference time status of a log header."""

    UNKNOWN = 20
    APPROXIMATE = 60
    COARSEADJUSTING = 80
    COARSE = 100
    COARSESTEERING = 120
    FREEWHEELING = 130
    FINEADJUSTING = 140
    FINE = 160
    FINEBACKUPSTEERING = 170
    FINESTEERING = 180
    SATTIME = 200


class ClockModelStatus(_OpenIntEnum):
    """Receiver clock model status (TIME, MARKTIME)."""

    VALID = 0
    CONVERGING = 1
    ITERATING = 2
    INVALID = 3
    ERROR = 4


class UTCStatus(_OpenIntEnum):
    """Validity of the UTC fields of the TIME log."""

    INVALID = 0
    VALID = 1
    WARNING = 2


class Datum(_OpenIntEnum):
    """Datum identifier of a position log (WGS84 = 61 in practice; USER = 63)."""

    ADIND = 1
    ARC50 = 2
    ARC60 = 3
    AGD66 = 4
    AGD84 = 5
    BUKIT = 6
    ASTRO = 7
    CHATM = 8
    CARTH = 9
    CAPE = 10
    DJAKA = 11
    EGYPT = 12
    ED50 = 13
    ED79 = 14
    GUNSG = 15
    GEO49 = 16
    GRB36 = 17
    GUAM = 18
    HAWAII = 19
    KAUAI = 20
    MAUI = 21
    OAHU = 22
    HERAT = 23
    HJORS = 24
    HONGK = 25
    HUTZU = 26
    INDIA = 27
    IRE65 = 28
    KERTA = 29
    KANDA = 30
    LIBER = 31
    LUZON = 32
    MINDA = 33
    MERCH = 34
    NAHR = 35
    NAD83 = 36
    CANADA = 37
    ALASKA = 38
    NAD27 = 39
    CARIBB = 40
    MEXICO = 41
    CAMER = 42
    MINNA = 43
    OMAN = 44
    PUERTO = 45
    QORNO = 46
    ROME = 47
    CHUA = 48
    SAM56 = 49
    SAM69 = 50
    CAMPO = 51
    SACOR = 52
    YACAR = 53
    TANAN = 54
    TIMBA = 55
    TOKYO = 56
    TRIST = 57
    VITI = 58
    WAK60 = 59
    WGS72 = 60
    WGS84 = 61
    ZANDE = 62
    USER = 63
    CSRS = 64
    ADIM = 65
    ARSM = 66
    ENW = 67
    HTN = 68
    INDB = 69
    INDI = 70
    IRL = 71
    LUZA = 72
    LUZB = 73
    NAHC = 74
    NASP = 75
    OGBM = 76
    OHAA = 77
    OHAB = 78
    OHAC = 79
    OHAD = 80
    OHIA = 81
    OHIB = 82
    OHIC = 83
    OHID = 84
    TIL = 85
    TOYM = 86


# --- Ports -----------------------------------------------------------------------------------
# The binary header holds one byte of the port address; ports whose address is >= 256 (USB1 =
# 0x5A0, ICOM1 = 0xFA0, …) keep only the low byte there (0xA0, which reads back as SPECIAL).
# ASCII headers carry the full name. Port names are therefore kept as strings.

_PORT_BASES: dict[str, int] = {
    "COM1": 0x20,
    "COM2": 0x40,
    "COM3": 0x60,
    "SPECIAL": 0xA0,
    "THISPORT": 0xC0,
    "FILE": 0xE0,
    "XCOM1": 0x1A0,
    "XCOM2": 0x2A0,
    "USB1": 0x5A0,
    "USB2": 0x6A0,
    "USB3": 0x7A0,
    "AUX": 0x8A0,
    "XCOM3": 0x9A0,
    "COM4": 0xBA0,
    "ETH1": 0xCA0,
    "IMU": 0xDA0,
    "ICOM1": 0xFA0,
    "ICOM2": 0x10A0,
    "ICOM3": 0x11A0,
    "NCOM1": 0x12A0,
    "NCOM2": 0x13A0,
    "NCOM3": 0x14A0,
    "ICOM4": 0x15A0,
    "WCOM1": 0x16A0,
    "COM5": 0x17A0,
    "COM6": 0x18A0,
    "BT1": 0x19A0,
    "COM7": 0x1AA0,
    "COM8": 0x1BA0,
    "COM9": 0x1CA0,
    "COM10": 0x1DA0,
    "CCOM1": 0x1EA0,
    "CCOM2": 0x1FA0,
    "CCOM3": 0x20A0,
    "CCOM4": 0x21A0,
    "CCOM5": 0x22A0,
    "CCOM6": 0x23A0,
    "ICOM5": 0x26A0,
    "ICOM6": 0x27A0,
    "ICOM7": 0x28A0,
    "SCOM1": 0x29A0,
    "SCOM2": 0x2AA0,
    "SCOM3": 0x2BA0,
    "SCOM4": 0x2CA0,
}

_PORT_ALL: dict[str, int] = {
    "NO_PORTS": 0,
    "COM1_ALL": 1,
    "COM2_ALL": 2,
    "COM3_ALL": 3,
    "THISPORT_ALL": 6,
    "FILE_ALL": 7,
    "ALL_PORTS": 8,
    "XCOM1_ALL": 9,
    "XCOM2_ALL": 10,
    "USB1_ALL": 13,
    "USB2_ALL": 14,
    "USB3_ALL": 15,
    "AUX_ALL": 16,
    "XCOM3_ALL": 17,
    "COM4_ALL": 19,
    "ETH1_ALL": 20,
    "IMU_ALL": 21,
    "ICOM1_ALL": 23,
    "ICOM2_ALL": 24,
    "ICOM3_ALL": 25,
    "NCOM1_ALL": 26,
    "NCOM2_ALL": 27,
    "NCOM3_ALL": 28,
    "ICOM4_ALL": 29,
    "WCOM1_ALL": 30,
}


def _build_port_tables() -> tuple[dict[str, int], dict[int, str]]:
    by_name: dict[str, int] = dict(_PORT_ALL)
    for base_name, base in _PORT_BASES.items():
        by_name[base_name] = base
        for sub in range(1, 32):  # virtual sub-ports COM1_1 … COM1_31
            by_name[f"{base_name}_{sub}"] = base + sub
    by_byte: dict[int, str] = {}
    for name, address in by_name.items():
        if address < 0x100:
            by_byte.setdefault(address, name)
    return by_name, by_byte


#: Full port address by name (ASCII header names), and name by one-byte binary port address.
PORT_ADDRESS, PORT_NAME_BY_BYTE = _build_port_tables()


def port_name_from_byte(address: int) -> str:
    """Port name for the one-byte port address of a binary header (``PORT<n>`` if unlisted)."""
    name = PORT_NAME_BY_BYTE.get(address)
    return name if name is not None else f"PORT{address}"


def port_byte_from_name(name: str) -> int:
    """One-byte binary port address for a port name (low byte of the full address).

    Raises:
        KeyError: the name is not a NovAtel port name.
    """
    address = PORT_ADDRESS.get(name)
    if address is None:
        if name.startswith("PORT") and name[4:].isdigit() and int(name[4:]) < 0x100:
            return int(name[4:])
        raise KeyError(name)
    return address & 0xFF


def enum_name(value: Any) -> Any:
    """An enum member as its name; anything else unchanged (for JSON views)."""
    return value.name if isinstance(value, IntEnum) else value
