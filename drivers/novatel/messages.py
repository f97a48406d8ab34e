"""Typed NovAtel records: log headers, the decoded log bodies, command responses and prompts.

A decoded log is a :class:`Log` = header (:class:`Header` for the long binary / ASCII /
abbreviated-ASCII header, :class:`ShortHeader` for short binary / short ASCII) + body. Bodies of
the logs this codec knows are frozen dataclasses whose fields follow the wire order of the
NovAtel OEM7 reference; every other log keeps its body untouched as :class:`RawBody`.

Field names carry their unit where it is not SI-obvious (``lat_deg``, ``hgt_m``,
``hor_spd_mps``, ``latency_s`` …). Angles stay in degrees here because that is what the receiver
reports; conversion to radians happens at the consumer (``vsccore.angles``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields, is_dataclass
from enum import Enum
from typing import Any, ClassVar, TypeVar

from drivers.novatel.enums import (
    ClockModelStatus,
    Datum,
    PositionType,
    SolutionStatus,
    TimeStatus,
    UTCStatus,
    _OpenIntEnum,
)
from vsccore.gpstime import gps_to_ns

#: NovAtel log name → message ID. The typed logs plus common logs that pass through raw, so
#: that ASCII and binary headers of those logs name each other.
LOG_IDS: dict[str, int] = {
    "LOG": 1,
    "LOGLIST": 5,
    "GPSEPHEM": 7,
    "IONUTC": 8,
    "VERSION": 37,
    "RAWEPHEM": 41,
    "BESTPOS": 42,
    "RANGE": 43,
    "PSRPOS": 47,
    "SATVIS": 48,
    "ALMANAC": 73,
    "TRACKSTAT": 83,
    "RXSTATUS": 93,
    "MATCHEDPOS": 96,
    "BESTVEL": 99,
    "PSRVEL": 100,
    "TIME": 101,
    "RXCONFIG": 128,
    "RANGECMP": 140,
    "RTKPOS": 141,
    "AVEPOS": 172,
    "PSRDOP": 174,
    "MARKPOS": 181,
    "RTKVEL": 216,
    "MARKTIME": 231,
    "BESTXYZ": 241,
    "PSRXYZ": 243,
    "RTKXYZ": 244,
    "RAWIMU": 268,
    "RAWIMUS": 325,
    "PDPPOS": 469,
    "INSPVA": 507,
    "INSPVAS": 508,
    "MARK2POS": 615,
    "MARK2TIME": 616,
    "BSLNXYZ": 686,
    "GLOEPHEMERIS": 723,
    "BESTUTM": 726,
    "CORRIMUDATA": 812,
    "HEADING": 971,
    "PSRDOP2": 1163,
    "BESTSATS": 1194,
    "MARK1TIME": 1130,
    "HEADING2": 1335,
    "INSPVAX": 1465,
}

#: Message ID → log name (inverse of :data:`LOG_IDS`).
LOG_NAMES: dict[int, str] = {v: k for k, v in LOG_IDS.items()}


def log_name_for_id(message_id: int) -> str:
    """Log name for a message ID (``MSG<id>`` when the ID is not in the table)."""
    name = LOG_NAMES.get(message_id)
    return name if name is not None else f"MSG{message_id}"


def log_id_for_name(name: str) -> int:
    """Message ID for a log name; 0 when unknown (no NovAtel log has ID 0)."""
    message_id = LOG_IDS.get(name)
    if message_id is not None:
        return message_id
    if name.startswith("MSG") and name[3:].isdigit():
        return int(name[3:])
    return 0


# --- Headers ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Header:
    """Long header shared by binary (28 bytes), ASCII (``#…;``) and abbreviated-ASCII logs.

    ``seconds`` is GPS seconds of week (the wire carries milliseconds). ``port`` is the port
    name (binary headers hold only the low byte of the port address, see ``enums``).
    ``source`` is the measurement source (0 = primary antenna; ASCII name suffix ``_1`` = 1) and
    ``response`` the binary response bit; both are 0/False for ordinary logs.
    """

    message_name: str
    message_id: int
    port: str
    sequence: int
    idle_time_pct: float
    time_status: TimeStatus
    week: int
    seconds: float
    receiver_status: int
    reserved: int
    sw_version: int
    source: int = 0
    response: bool = False

    @property
    def gps_ns(self) -> int:
        """Log time as integer ns since the GPS epoch."""
        return gps_to_ns(self.week, self.seconds)


@dataclass(frozen=True, slots=True)
class ShortHeader:
    """Short header (binary ``AA 44 13``, 12 bytes; ASCII ``%NAMEA,week,seconds;``)."""

    message_name: str
    message_id: int
    week: int
    seconds: float

    @property
    def gps_ns(self) -> int:
        """Log time as integer ns since the GPS epoch."""
        return gps_to_ns(self.week, self.seconds)


AnyHeader = Header | ShortHeader


# --- Bodies ----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class PositionSolution:
    """Geodetic position solution: the layout of BESTPOS, MARKPOS and MARK2POS (72 bytes)."""

    MESSAGE_NAME: ClassVar[str] = ""
    MESSAGE_ID: ClassVar[int] = 0

    sol_status: SolutionStatus
    pos_type: PositionType
    lat_deg: float
    lon_deg: float
    hgt_m: float  # height above mean sea level
    undulation_m: float  # geoid − ellipsoid separation; ellipsoidal height = hgt_m + undulation_m
    datum: Datum
    lat_sigma_m: float
    lon_sigma_m: float
    hgt_sigma_m: float
    stn_id: str
    diff_age_s: float
    sol_age_s: float
    num_svs: int
    num_soln_svs: int
    num_soln_l1_svs: int
    num_soln_multi_svs: int
    reserved: int
    ext_sol_stat: int
    galileo_beidou_sig_mask: int
    gps_glonass_sig_mask: int


@dataclass(frozen=True, slots=True)
class BestPos(PositionSolution):
    """BESTPOS (42): best available position."""

    MESSAGE_NAME: ClassVar[str] = "BESTPOS"
    MESSAGE_ID: ClassVar[int] = 42


@dataclass(frozen=True, slots=True)
class MarkPos(PositionSolution):
    """MARKPOS (181): position at the time of an event on the MARK1 input."""

    MESSAGE_NAME: ClassVar[str] = "MARKPOS"
    MESSAGE_ID: ClassVar[int] = 181


@dataclass(frozen=True, slots=True)
class Mark2Pos(PositionSolution):
    """MARK2POS (615): position at the time of an event on the MARK2 input."""

    MESSAGE_NAME: ClassVar[str] = "MARK2POS"
    MESSAGE_ID: ClassVar[int] = 615


@dataclass(frozen=True, slots=True)
class BestVel:
    """BESTVEL (99): best available velocity; track over ground is clockwise from true north."""

    MESSAGE_NAME: ClassVar[str] = "BESTVEL"
    MESSAGE_ID: ClassVar[int] = 99

    sol_status: SolutionStatus
    vel_type: PositionType
    latency_s: float
    diff_age_s: float
    hor_spd_mps: float
    trk_gnd_deg: float
    vert_spd_mps: float
    reserved: float


@dataclass(frozen=True, slots=True)
class BestXyz:
    """BESTXYZ (241): best position and velocity in ECEF (112 bytes)."""

    MESSAGE_NAME: ClassVar[str] = "BESTXYZ"
    MESSAGE_ID: ClassVar[int] = 241

    p_sol_status: SolutionStatus
    pos_type: PositionType
    p_x_m: float
    p_y_m: float
    p_z_m: float
    p_x_sigma_m: float
    p_y_sigma_m: float
    p_z_sigma_m: float
    v_sol_status: SolutionStatus
    vel_type: PositionType
    v_x_mps: float
    v_y_mps: float
    v_z_mps: float
    v_x_sigma_mps: float
    v_y_sigma_mps: float
    v_z_sigma_mps: float
    stn_id: str
    v_latency_s: float
    diff_age_s: float
    sol_age_s: float
    num_svs: int
    num_soln_svs: int
    num_soln_l1_svs: int
    num_soln_multi_svs: int
    reserved: int
    ext_sol_stat: int
    galileo_beidou_sig_mask: int
    gps_glonass_sig_mask: int


@dataclass(frozen=True, slots=True)
class EventTime:
    """Time of an event-input edge: the layout of MARKTIME and MARK2TIME (40 bytes).

    ``week``/``seconds`` are GPS time of the edge; UTC = GPS + offset_s + utc_offset_s.
    """

    MESSAGE_NAME: ClassVar[str] = ""
    MESSAGE_ID: ClassVar[int] = 0

    week: int
    seconds: float
    offset_s: float
    offset_std_s: float
    utc_offset_s: float
    clock_status: ClockModelStatus

    @property
    def event_gps_ns(self) -> int:
        """Event time as integer ns since the GPS epoch."""
        return gps_to_ns(self.week, self.seconds)


@dataclass(frozen=True, slots=True)
class MarkTime(EventTime):
    """MARKTIME (231): GPS time of the MARK1 event input."""

    MESSAGE_NAME: ClassVar[str] = "MARKTIME"
    MESSAGE_ID: ClassVar[int] = 231


@dataclass(frozen=True, slots=True)
class Mark1Time(MarkTime):
    """MARK1TIME (1130): GPS time of the MARK1 event input, the replacement of the deprecated MARKTIME (231).

    Same body as MARKTIME (OEM7 Commands and Logs Reference, MARK1TIME … MARK4TIME), so code that
    takes a :class:`MarkTime` takes this too.
    """

    MESSAGE_NAME: ClassVar[str] = "MARK1TIME"
    MESSAGE_ID: ClassVar[int] = 1130


@dataclass(frozen=True, slots=True)
class Mark2Time(EventTime):
    """MARK2TIME (616): GPS time of the MARK2 event input."""

    MESSAGE_NAME: ClassVar[str] = "MARK2TIME"
    MESSAGE_ID: ClassVar[int] = 616


@dataclass(frozen=True, slots=True)
class Time:
    """TIME (101): receiver clock model and UTC.

    ``utc_offset_s`` is UTC − GPS as the receiver reports it (e.g. −18.0 in 2017+), so the GPS−UTC
    leap-second count is :attr:`leap_seconds` = −utc_offset_s.
    """

    MESSAGE_NAME: ClassVar[str] = "TIME"
    MESSAGE_ID: ClassVar[int] = 101

    clock_status: ClockModelStatus
    offset_s: float
    offset_std_s: float
    utc_offset_s: float
    utc_year: int
    utc_month: int
    utc_day: int
    utc_hour: int
    utc_min: int
    utc_ms: int
    utc_status: UTCStatus

    @property
    def leap_seconds(self) -> int:
        """GPS − UTC in whole seconds (for ``vsccore.gpstime.gps_ns_to_unix_ns``)."""
        return -round(self.utc_offset_s)


@dataclass(frozen=True, slots=True)
class Heading:
    """HEADING (971): heading of the dual-antenna baseline, master → rover (44 bytes).

    ``heading_deg`` is an azimuth, clockwise from true north, 0…360.
    """

    MESSAGE_NAME: ClassVar[str] = "HEADING"
    MESSAGE_ID: ClassVar[int] = 971

    sol_status: SolutionStatus
    pos_type: PositionType
    length_m: float
    heading_deg: float
    pitch_deg: float
    reserved: float
    heading_sigma_deg: float
    pitch_sigma_deg: float
    stn_id: str
    num_svs: int
    num_soln_svs: int
    num_obs: int
    num_multi: int
    sol_source: int
    ext_sol_stat: int
    galileo_beidou_sig_mask: int
    gps_glonass_sig_mask: int


@dataclass(frozen=True, slots=True)
class Heading2:
    """HEADING2 (1335): heading with rover and master station IDs (48 bytes)."""

    MESSAGE_NAME: ClassVar[str] = "HEADING2"
    MESSAGE_ID: ClassVar[int] = 1335

    sol_status: SolutionStatus
    pos_type: PositionType
    length_m: float
    heading_deg: float
    pitch_deg: float
    reserved: float
    heading_sigma_deg: float
    pitch_sigma_deg: float
    rover_stn_id: str
    master_stn_id: str
    num_svs: int
    num_soln_svs: int
    num_obs: int
    num_multi: int
    sol_source: int
    ext_sol_stat: int
    galileo_beidou_sig_mask: int
    gps_glonass_sig_mask: int


@dataclass(frozen=True, slots=True)
class PsrDop:
    """PSRDOP (174): dilution of precision of the pseudorange solution and the PRNs used."""

    MESSAGE_NAME: ClassVar[str] = "PSRDOP"
    MESSAGE_ID: ClassVar[int] = 174

    gdop: float
    pdop: float
    hdop: float
    htdop: float
    tdop: float
    cutoff_deg: float
    prns: tuple[int, ...] = field(default=())


class ComponentType(_OpenIntEnum):
    """Component type of a VERSION entry (OEM7 Commands and Logs Reference, VERSION, Component Types)."""

    UNKNOWN = 0
    GPSCARD = 1
    CONTROLLER = 2
    ENCLOSURE = 3
    IMUCARD = 7
    USERINFO = 8
    OEM6FPGA = 12
    GPSCARD2 = 13
    BLUETOOTH = 14
    WIFI = 15
    CELLULAR = 16
    RADIO = 18
    WWW_CONTENT = 19
    REGULATORY = 20
    OEM7FPGA = 21
    APPLICATION = 22
    PACKAGE = 23
    DEFAULT_CONFIG = 25
    WHEELSENSOR = 26
    EMBEDDED_AUTH = 27
    DB_HEIGHTMODEL = 981073920
    DB_USERAPP = 981073921
    DB_USERAPPAUTO = 981073925
    DB_WWWISO = 981073928
    DB_LUA_SCRIPTS = 981073930


@dataclass(frozen=True, slots=True)
class VersionComponent:
    """One component of a VERSION log (108 bytes binary): card type, model, product serial number (PSN),
    hardware, software and boot versions, and the software's compile date and time."""

    MESSAGE_NAME: ClassVar[str] = "VERSION"
    MESSAGE_ID: ClassVar[int] = 37

    component_type: ComponentType
    model: str
    psn: str
    hw_version: str
    sw_version: str
    boot_version: str
    compile_date: str
    compile_time: str


@dataclass(frozen=True, slots=True)
class Version:
    """VERSION (37): a ulong count, then one :class:`VersionComponent` per component of the receiver.

    The codec keeps VERSION as :class:`RawBody` in the stream; ``drivers.novatel.layouts.decode_version``
    turns it into this on demand (the PSN identifies a receiver).
    """

    MESSAGE_NAME: ClassVar[str] = "VERSION"
    MESSAGE_ID: ClassVar[int] = 37

    components: tuple[VersionComponent, ...]

    def component(self, kind: ComponentType = ComponentType.GPSCARD) -> VersionComponent | None:
        """The first component of a kind (the GNSS card by default), None when there is none."""
        return next((c for c in self.components if c.component_type == kind), None)


class BodyFormat(Enum):
    """Wire form that a :class:`RawBody` was taken from."""

    BINARY = "binary"
    ASCII = "ascii"
    ABBREVIATED = "abbreviated"


@dataclass(frozen=True, slots=True)
class RawBody:
    """Body of a log this codec does not decode (or could not), kept byte-exact.

    ``data`` is the binary body (between header and CRC), the ASCII body (between ``;`` and
    ``*``), or the abbreviated-ASCII continuation lines as received.
    """

    data: bytes
    fmt: BodyFormat


Message = (
    BestPos | MarkPos | Mark2Pos | BestVel | BestXyz | MarkTime | Mark1Time | Mark2Time | Time | Heading | Heading2
    | PsrDop
)
Body = Message | RawBody

#: Typed body classes by message ID.
MESSAGE_TYPES: dict[int, type[Message]] = {
    cls.MESSAGE_ID: cls
    for cls in (
        BestPos, MarkPos, Mark2Pos, BestVel, BestXyz, MarkTime, Mark1Time, Mark2Time, Time, Heading, Heading2, PsrDop
    )
}


@dataclass(frozen=True, slots=True)
class Log:
    """A decoded NovAtel log: header plus typed (or raw) body."""

    header: Header | ShortHeader
    body: Body

    @property
    def name(self) -> str:
        """Log name without format suffix, e.g. ``BESTPOS``."""
        return self.header.message_name


@dataclass(frozen=True, slots=True)
class Response:
    """Abbreviated-ASCII command response: ``<OK`` (ok=True) or ``<ERROR:text`` (ok=False)."""

    ok: bool
    text: str


@dataclass(frozen=True, slots=True)
class Prompt:
    """Interactive port prompt such as ``[COM1]``, ``[USB1]`` or ``[ICOM1]``."""

    port: str


def make_header(
    body: Message | type[Message],
    *,
    week: int,
    seconds: float,
    port: str = "COM1",
    sequence: int = 0,
    idle_time_pct: float = 0.0,
    time_status: TimeStatus = TimeStatus.FINESTEERING,
    receiver_status: int = 0,
    reserved: int = 0,
    sw_version: int = 0,
    source: int = 0,
) -> Header:
    """Long header for a typed body (name and ID taken from its class)."""
    cls = body if isinstance(body, type) else type(body)
    return Header(
        message_name=cls.MESSAGE_NAME,
        message_id=cls.MESSAGE_ID,
        port=port,
        sequence=sequence,
        idle_time_pct=idle_time_pct,
        time_status=time_status,
        week=week,
        seconds=seconds,
        receiver_status=receiver_status,
        reserved=reserved,
        sw_version=sw_version,
        source=source,
    )


def make_short_header(body: Message | type[Message], *, week: int, seconds: float) -> ShortHeader:
    """Short header for a typed body."""
    cls = body if isinstance(body, type) else type(body)
    return ShortHeader(message_name=cls.MESSAGE_NAME, message_id=cls.MESSAGE_ID, week=week, seconds=seconds)


_T = TypeVar("_T")

# --- Fast construction of frozen records -----------------------------------------------------
# Decoding builds four frozen dataclasses per frame (header, body, log, frame) with up to 28
# fields each; their generated ``__init__`` (``object.__setattr__`` per field) and even a direct
# store through each slot's member descriptor cost more than the whole wire decode. CPython
# stores into a *plain* slotted class's slots with a specialised STORE_ATTR (no call), and lets
# an object change its ``__class__`` to any class with the same slot layout. So a record is
# built as an instance of a mutable "twin" class with the same slots and then given its real,
# frozen class: the result is an ordinary instance of the dataclass (equality, hashing, repr,
# pickling, ``dataclasses.replace`` and frozenness unchanged). The twin is checked when it is
# made; where the interpreter refuses the class change, the emitter falls back to descriptor
# stores.

_TWINS: dict[type, type | None] = {}


def slot_twin(cls: type) -> type | None:
    """Mutable class with the slot layout of slotted class ``cls`` (None when not possible).

    ``obj = object.__new__(twin)``, plain attribute stores, then ``obj.__class__ = cls`` gives a
    fully initialised instance of ``cls`` without running its ``__init__``/``__setattr__``.
    """
    layers = [k for k in cls.__mro__[:-1] if vars(k).get("__slots__")]
    if len(layers) != 1 or "__dict__" in vars(cls) or isinstance(vars(layers[0])["__slots__"], str):
        return None
    layer = layers[0]
    if layer in _TWINS:
        twin = _TWINS[layer]
    else:
        slots = tuple(vars(layer)["__slots__"])
        twin = type(f"_{layer.__name__}Twin", (), {"__slots__": slots, "__module__": cls.__module__})
        _TWINS[layer] = twin
    if twin is None:
        return None
    probe: Any = object.__new__(twin)
    for name in vars(layer)["__slots__"]:
        setattr(probe, name, None)
    try:
        probe.__class__ = cls
    except TypeError:
        return None
    return twin


class RecordEmitter:
    """Emits lines of generated Python that build one instance of a frozen slotted dataclass.

    ``begin()``, then ``store(field, expression)`` for every field, then ``end()``; the names the
    lines use are put into the generated code's namespace ``ns``. ``use_twin=False`` forces the
    slower descriptor stores (the twin-less fallback, kept testable).
    """

    __slots__ = ("_fields", "_stored", "_tag", "_twin", "cls", "var")

    def __init__(self, cls: type, var: str, ns: dict[str, Any], *, use_twin: bool = True) -> None:
        if not is_dataclass(cls) or "__slots__" not in vars(cls) or hasattr(cls, "__post_init__"):
            raise TypeError(f"{cls.__name__} is not a slotted dataclass without __post_init__")
        self.cls = cls
        self.var = var
        self._tag = f"{var}_{cls.__name__}"
        self._fields = tuple(f.name for f in fields(cls))
        self._stored: set[str] = set()
        self._twin = slot_twin(cls) if use_twin else None
        ns["_new"] = object.__new__
        ns[f"_cls_{self._tag}"] = cls
        if self._twin is not None:
            ns[f"_twin_{self._tag}"] = self._twin
        else:
            for name in self._fields:
                ns[f"_set_{self._tag}_{name}"] = getattr(cls, name).__set__

    @property
    def fields(self) -> tuple[str, ...]:
        return self._fields

    def begin(self) -> str:
        self._stored.clear()
        kind = "twin" if self._twin is not None else "cls"
        return f"{self.var} = _new(_{kind}_{self._tag})"

    def store(self, name: str, expr: str) -> str:
        if name not in self._fields:
            raise TypeError(f"{self.cls.__name__} has no field {name!r}")
        self._stored.add(name)
        if self._twin is not None:
            return f"{self.var}.{name} = {expr}"
        return f"_set_{self._tag}_{name}({self.var}, {expr})"

    def end(self) -> str:
        missing = [name for name in self._fields if name not in self._stored]
        if missing:  # an unset slot would only fail later, on first access
            raise TypeError(f"generated {self.cls.__name__} leaves fields unset: {', '.join(missing)}")
        return f"{self.var}.__class__ = _cls_{self._tag}" if self._twin is not None else "pass"


def compile_function(name: str, lines: list[str], ns: dict[str, Any]) -> Callable[..., Any]:
    """Compile generated source (built only from field tables and identifiers) into a function."""
    source = "\n".join(lines) + "\n"
    exec(compile(source, f"<generated {name}>", "exec"), ns)  # no outside input reaches the source
    function: Callable[..., Any] = ns[name]
    return function


def fast_constructor(cls: type[_T], *, use_twin: bool = True) -> Callable[..., _T]:
    """Positional constructor of a frozen slotted dataclass that skips the generated ``__init__``.

    Takes every field positionally (defaults are not applied) and returns an instance
    indistinguishable from ``cls(*args)``. Only for dataclasses that define no
    ``__post_init__``.
    """
    ns: dict[str, Any] = {}
    emit = RecordEmitter(cls, "obj", ns, use_twin=use_twin)
    args = [f"a{i}" for i in range(len(emit.fields))]
    lines = [f"def new_{cls.__name__}({', '.join(args)}):", "    " + emit.begin()]
    lines += ["    " + emit.store(name, arg) for name, arg in zip(emit.fields, args, strict=True)]
    lines += ["    " + emit.end(), "    return obj"]
    return compile_function(f"new_{cls.__name__}", lines, ns)


#: Fast positional constructors of the records built on every decoded frame.
new_header = fast_constructor(Header)
new_short_header = fast_constructor(ShortHeader)
new_log = fast_constructor(Log)
