"""Post-processed kinematic (PPK) solutions of a recorded session with RTKLIB (``rig ppk``).

Per rover: the session's raw streams are exported (:func:`rig.export.raw_gnss.export_raw_gnss`), the rover's
NovAtel stream (RANGECMPB, GPS and GLONASS records) and the relayed base corrections (RTCM3 MSM +
1005/1006) are turned into RINEX observations by Debian RTKLIB's ``convbin``, a RINEX 3 navigation
file is written from the rover's decoded GPSEPHEM and GLOEPHEMERIS logs (RTKLIB 2.4.3 reads GPS
ephemerides from RAWEPHEMB only; see docs/decisions/0004-ppk-with-debian-rtklib.md), and ``rnx2rtkp``
solves in kinematic mode, forward and backward combined, L1+L2, against the base position the
corrections carry (RTCM 1005/1006), with GPS and GLONASS (:data:`SYSTEMS`). GLONASS ambiguities are
fixed too (``pos2-gloarmode = on``): that assumes no inter-channel (FDMA) biases between the rover and
the base, which holds for the simulator and for two receivers of one make.

Before solving, each rover's systems are decided (:func:`usable_systems`): a system is used only where the
rover's RINEX observations, the base's and the rover's ephemeris logs all have it. A system left out is a
warning naming the rover, the system and the log to add (an older session without GLOEPHEMERISB is solved
with GPS alone, and says so). A system asked for explicitly (``systems=``, ``rig ppk --systems``) that no
rover can use is an error; the default (:data:`SYSTEMS`) never fails for a missing optional system. GPS
ephemerides (GPSEPHEMB) and raw observations (RANGECMPB) are required whenever GPS is solved with.

The solutions of every rover go into one side file next to the session, ``<base>.ppk.parquet``
(:func:`ppk_file_path`, :data:`PPK_COLUMNS`), which :mod:`rig.data.inputs` reads. RTKLIB runs as
subprocesses with timeouts: a crash or a hang fails one call with the command, its exit status and
its stderr named, never the ``rig`` process.
"""

from __future__ import annotations

import datetime as dt
import math
import re
import shutil
import subprocess
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from drivers.novatel import FrameReader
from drivers.novatel.rawobs import GloEphemeris, GpsEphem, decode_gloephemeris, decode_gpsephem
from rig.data.sidefiles import PPK_METADATA_KEY, PpkQuality, ppk_file_path
from vsccore.errors import AnalysisError, DecodeError, RigError, SessionFileError

__all__ = [
    "SYSTEMS",
    "SYSTEM_NAMES",
    "PpkRover",
    "PpkRun",
    "RtklibMissingError",
    "run_ppk",
    "usable_systems",
    "write_rinex_nav",
]

RTKLIB_PACKAGE = "rtklib"
"""The Debian package with ``convbin`` and ``rnx2rtkp``."""
TOOLS = ("convbin", "rnx2rtkp")
DEFAULT_TIMEOUT_S = 600.0
"""Per RTKLIB call (rnx2rtkp on an hour at 20 Hz takes minutes, not tens of minutes)."""
ELEVATION_MASK_DEG = 10.0
SYSTEMS = ("G", "R")
"""Satellite systems rnx2rtkp solves with by default: GPS and GLONASS (RINEX letters), each where the session
has what it needs (see :func:`usable_systems`)."""
SYSTEM_NAMES = {"G": "GPS", "R": "GLONASS"}
"""The systems ``rig ppk`` can solve with (it writes navigation data from these systems' ephemeris logs)."""
EPHEMERIS_LOGS = {"G": "GPSEPHEMB", "R": "GLOEPHEMERISB"}
"""The rover log with each system's broadcast ephemerides."""
BASE_MSM = {"G": "RTCM1077", "R": "RTCM1087"}
"""The base's RTCM3 observation message (MSM7) per system."""
_NAVSYS = {"G": 1, "S": 2, "R": 4, "E": 8, "J": 16, "C": 32}  # RTKLIB's pos1-navsys bits
_OTHER_SYSTEMS = {"S": "SBAS", "E": "Galileo", "J": "QZSS", "C": "BeiDou"}

_GPS_EPOCH = dt.datetime(1980, 1, 6)
_NS = 1_000_000_000
_WEEK_NS = 7 * 86400 * _NS
_GPS_UNIX_OFFSET_NS = 315_964_800 * _NS


class RtklibMissingError(RigError, OSError):
    """RTKLIB's command-line tools are not installed (the message names the Debian package)."""


@dataclass(frozen=True, slots=True)
class PpkRover:
    """One rover's PPK run."""

    rover: str
    epochs: int
    """Epochs with a solution."""
    fixed: int
    """Epochs with Q = 1 (ambiguities fixed)."""
    observation_epochs: int
    """RANGECMP logs in the rover's stream."""
    satellites_median: float
    glonass_ephemerides: int = 0
    """GLOEPHEMERIS sets written to the navigation file (0: GPS-only solution)."""
    systems: tuple[str, ...] = ()
    """The satellite systems rnx2rtkp solved this rover with (RINEX letters; see :func:`usable_systems`)."""

    @property
    def systems_text(self) -> str:
        """``GPS + GLONASS``, ``GPS only``."""
        names = [SYSTEM_NAMES.get(s, s) for s in self.systems]
        return f"{names[0]} only" if len(names) == 1 else " + ".join(names)

    @property
    def fix_ratio(self) -> float:
        """Fixed epochs / observation epochs (0 when there were none)."""
        return self.fixed / self.observation_epochs if self.observation_epochs else 0.0


@dataclass(frozen=True, slots=True)
class PpkRun:
    """What ``rig ppk`` did: the side file and each rover's figures."""

    out: Path
    rovers: tuple[PpkRover, ...]
    warnings: tuple[str, ...] = ()


def _tools() -> dict[str, str]:
    found = {t: shutil.which(t) for t in TOOLS}
    missing = [t for t, p in found.items() if p is None]
    if missing:
        raise RtklibMissingError(
            f"RTKLIB's {' and '.join(missing)} not found on PATH: install Debian's {RTKLIB_PACKAGE!r} package "
            f"(apt-get install {RTKLIB_PACKAGE})"
        )
    return {t: p for t, p in found.items() if p is not None}


def _run(cmd: Sequence[str], what: str, timeout_s: float, cwd: Path) -> subprocess.CompletedProcess[str]:
    try:
        res = subprocess.run(list(cmd), capture_output=True, text=True, timeout=timeout_s, check=False, cwd=cwd)
    except subprocess.TimeoutExpired as exc:
        raise AnalysisError(f"{what}: {' '.join(cmd)} did not finish within {timeout_s:g} s") from exc
    except OSError as exc:
        raise RtklibMissingError(f"{what}: cannot run {cmd[0]} ({exc}); install Debian's {RTKLIB_PACKAGE!r} "
                                 "package") from exc
    if res.returncode != 0:
        tail = (res.stderr or res.stdout).strip().splitlines()[-3:]
        raise AnalysisError(f"{what}: {' '.join(cmd)} exited with status {res.returncode}: {' / '.join(tail)}")
    return res


# --- the rover's stream ------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _RoverStream:
    rangecmp: int
    ephemerides: tuple[GpsEphem, ...]
    first_gps_ns: int | None
    glonass: tuple[GloEphemeris, ...] = ()


def _scan_rover(path: Path, rover: str) -> _RoverStream:
    ephs: dict[tuple[int, int, float], GpsEphem] = {}
    glo: dict[tuple[int, int, int], GloEphemeris] = {}
    n = 0
    first: int | None = None
    with open(path, "rb") as f:
        for fr in FrameReader(f):
            if fr.log is None:
                continue
            name = fr.log.header.message_name
            if name == "RANGECMP":
                n += 1
                if first is None:
                    first = fr.log.header.gps_ns
            elif name == "GPSEPHEM":
                try:
                    e = decode_gpsephem(fr.log.body)  # type: ignore[arg-type]
                except DecodeError as exc:
                    raise AnalysisError(f"{path}: rover {rover}: undecodable GPSEPHEM log: {exc}") from exc
                ephs[(e.prn, e.iode1, e.toe_s)] = e
            elif name == "GLOEPHEMERIS":
                try:
                    g = decode_gloephemeris(fr.log.body)  # type: ignore[arg-type]
                except DecodeError as exc:
                    raise AnalysisError(f"{path}: rover {rover}: undecodable GLOEPHEMERIS log: {exc}") from exc
                glo[(g.slot, g.ephem_week, g.ephem_time_ms)] = g
    return _RoverStream(n, tuple(ephs.values()), first, tuple(glo.values()))


def _d19(x: float) -> str:
    return f"{x:19.12E}".replace("E", "D")


def write_rinex_nav(ephemerides: Iterable[GpsEphem], path: Path, glonass: Iterable[GloEphemeris] = ()) -> int:
    """Write broadcast ephemerides (decoded GPSEPHEM, and GLOEPHEMERIS) as a RINEX 3.04 navigation file (mixed when
    there are GLONASS sets); returns how many.

    A GLONASS record is stamped in UTC (tb − the leap seconds GLOEPHEMERIS's GPS-GLONASS offset implies) with
    −τn, +γn and the frame time in seconds of the UTC week; position, velocity and lunisolar acceleration in km.

    Raises:
        AnalysisError: an ephemeris with a non-finite parameter (named by PRN and IODE, or slot and tb).
    """
    glo = sorted(glonass, key=lambda g: (g.slot, g.ephem_week, g.ephem_time_ms))
    kind = "M: MIXED" if glo else "G: GPS"
    lines = [f"{'3.04':>9}{'':11}{'N: GNSS NAV DATA':<20}{kind:<20}RINEX VERSION / TYPE",
             f"{'vsc-rig ppk':<20}{'':<20}{'':<20}PGM / RUN BY / DATE",
             f"{'':60}END OF HEADER"]
    n = 0
    for e in sorted(ephemerides, key=lambda e: (e.prn, e.week, e.toc_s)):
        toc = _GPS_EPOCH + dt.timedelta(weeks=e.week, seconds=e.toc_s)
        rows = [
            (e.iode1, e.crs_m, e.delta_n_rad_s, e.m0_rad),
            (e.cuc_rad, e.ecc, e.cus_rad, math.sqrt(e.a_m)),
            (e.toe_s, e.cic_rad, e.omega0_rad, e.cis_rad),
            (e.i0_rad, e.crc_m, e.omega_rad, e.omega_dot_rad_s),
            (e.idot_rad_s, 1.0, e.week, 0.0),  # codes on L2: C/A; GPS week; L2 P data flag
            (math.sqrt(e.ura_var_m2) if e.ura_var_m2 > 0 else 2.0, e.health, e.tgd_s, e.iodc),
            (e.tow_s, 4.0),  # transmission time; fit interval (h)
        ]
        values = [float(v) for r in rows for v in r] + [e.af0_s, e.af1_s_s, e.af2_s_s2]
        if not all(math.isfinite(v) for v in values):
            raise AnalysisError(f"GPSEPHEM PRN {e.prn} IODE {e.iode1}: non-finite orbit parameter")
        lines.append(f"G{e.prn:02d} {toc:%Y %m %d %H %M %S}{_d19(e.af0_s)}{_d19(e.af1_s_s)}{_d19(e.af2_s_s2)}")
        lines.extend("    " + "".join(_d19(float(v)) for v in r) for r in rows)
        n += 1
    for g in glo:
        leap = 3 * 3600 - g.time_offset_s
        utc_s = g.ephem_week * 604800 + g.ephem_time_ms // 1000 - leap
        toc = _GPS_EPOCH + dt.timedelta(seconds=utc_s)
        # frame start (tk, seconds of the GLONASS day) as seconds of the UTC week
        glo_day_start = utc_s + 3 * 3600 - (utc_s + 3 * 3600) % 86400
        frame = (glo_day_start + g.tk_s - 3 * 3600) % 604800
        grows = [(g.pos_x_m / 1e3, g.vel_x_mps / 1e3, g.ls_acc_x_mps2 / 1e3, 0.0 if g.healthy else 1.0),
                 (g.pos_y_m / 1e3, g.vel_y_mps / 1e3, g.ls_acc_y_mps2 / 1e3, float(g.fcn)),
                 (g.pos_z_m / 1e3, g.vel_z_mps / 1e3, g.ls_acc_z_mps2 / 1e3, float(g.age_days))]
        head = (-g.tau_n_s, g.gamma_n, float(frame))
        if not all(math.isfinite(v) for v in (*head, *(v for r in grows for v in r))):
            raise AnalysisError(f"GLOEPHEMERIS slot {g.slot} tb {g.ephem_time_ms / 1000:g} s: non-finite parameter")
        lines.append(f"R{g.slot:02d} {toc:%Y %m %d %H %M %S}" + "".join(_d19(v) for v in head))
        lines.extend("    " + "".join(_d19(v) for v in r) for r in grows)
        n += 1
    path.write_text("\n".join(lines) + "\n")
    return n


# --- RINEX / .pos helpers ------------------------------------------------------------------------

_APPROX = re.compile(r"^(.{14})(.{14})(.{14})\s*APPROX POSITION XYZ")
_DELTA = re.compile(r"^(.{14})(.{14})(.{14})\s*ANTENNA: DELTA H/E/N")


def _approx_position(obs: Path) -> tuple[float, float, float] | None:
    """The base antenna's ECEF position from a RINEX header: the reference point RTCM 1005/1006 gives
    (APPROX POSITION XYZ) raised by the antenna height 1006 gives (ANTENNA: DELTA H/E/N), as RTKLIB
    does with a position taken from the header. None: no plausible position."""
    import pymap3d

    xyz: tuple[float, ...] | None = None
    delta = (0.0, 0.0, 0.0)
    with open(obs) as f:
        for line in f:
            if "END OF HEADER" in line:
                break
            if (m := _APPROX.match(line)) is not None:
                xyz = tuple(float(v) for v in m.groups())
            elif (m := _DELTA.match(line)) is not None:
                delta = (float(m.group(1)), float(m.group(2)), float(m.group(3)))
    if xyz is None or not math.hypot(*xyz) > 6.0e6:
        return None
    h_up, d_east, d_north = delta
    lat, lon, _h = pymap3d.ecef2geodetic(*xyz)
    dx, dy, dz = pymap3d.enu2uvw(d_east, d_north, h_up, lat, lon)
    return xyz[0] + float(dx), xyz[1] + float(dy), xyz[2] + float(dz)


def _is_rinex_obs(path: Path) -> bool:
    """A RINEX observation file (its first line says so), not a binary RTCM3 stream."""
    try:
        with open(path, "rb") as f:
            first = f.read(80)
    except OSError as exc:
        raise SessionFileError(f"{path}: cannot read the base observations: {exc}") from exc
    return first[60:80].startswith(b"RINEX VERSION / TYPE") and first[20:21] == b"O"


def _rinex_obs_systems(path: Path, wanted: Iterable[str]) -> set[str]:
    """The systems (of ``wanted``) with at least one observation line in a RINEX 3 observation file (the first
    field of a body line names the satellite: ``G05``, ``R14``); stops reading once every wanted one was seen."""
    want = set(wanted)
    seen: set[str] = set()
    body = False
    try:
        with open(path) as f:
            for line in f:
                if not body:
                    body = "END OF HEADER" in line
                    continue
                s = line[:1]
                if s in want and s not in seen and line[1:3].strip().isdigit():
                    seen.add(s)
                    if seen == want:
                        break
    except OSError as exc:
        raise SessionFileError(f"{path}: cannot read the RINEX observations: {exc}") from exc
    return seen


def usable_systems(rover: str, asked: Sequence[str], *, rover_obs: Iterable[str], ephemerides: Iterable[str],
                   base_obs: Iterable[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The systems of ``asked`` that ``rover`` can be solved with, and a note per system left out.

    A system is used when the rover's observations (its RINEX obs from RANGECMPB), its decoded ephemerides
    and the base's observations all have it. Each note names the rover, the system, what is missing and the
    log to add, e.g. ``rover_b: no GLOEPHEMERISB in the session; GLONASS not used for rover_b — log
    GLOEPHEMERISB ONCHANGED on rover_b (see examples/car-template.toml)``.
    """
    obs, eph, base = set(rover_obs), set(ephemerides), set(base_obs)
    used: list[str] = []
    notes: list[str] = []
    for s in asked:
        name = SYSTEM_NAMES.get(s, s)
        why: list[str] = []
        todo: list[str] = []
        if s not in eph:
            why.append(f"no {EPHEMERIS_LOGS[s]} in the session")
            todo.append(f"log {EPHEMERIS_LOGS[s]} ONCHANGED on {rover}")
        if s not in obs:
            why.append(f"no {name} observations in its RANGECMPB")
            todo.append(f"let {rover} track {name}")
        if s not in base:
            why.append(f"no {name} observations in the base corrections")
            todo.append(f"log {BASE_MSM[s]} on the base")
        if why:
            notes.append(f"{rover}: {' and '.join(why)}; {name} not used for {rover} — {' and '.join(todo)} "
                         "(see examples/car-template.toml)")
        else:
            used.append(s)
    return tuple(used), tuple(notes)


def _read_pos(path: Path) -> npt.NDArray[np.float64]:
    """rnx2rtkp's default output (GPS week, TOW, lat, lon, h, Q, ns, sdn, sde, sdu, …, age, ratio) as rows."""
    rows: list[list[float]] = []
    with open(path) as f:
        for line in f:
            if not line.strip() or line.startswith("%"):
                continue
            parts = line.split()
            if len(parts) < 15:
                raise AnalysisError(f"{path}: unexpected rnx2rtkp output line {line.strip()!r}")
            rows.append([float(p) for p in parts[:15]])
    return np.asarray(rows, dtype=float).reshape(-1, 15)


# --- the command ----------------------------------------------------------------------------------


def _receiver_names(session_path: Path) -> list[str]:
    from rig.data import load_session

    cfg = load_session(session_path, topics=()).config
    receivers = cfg.get("receivers", [])
    items = receivers.values() if isinstance(receivers, dict) else receivers
    return [str(r["name"]) for r in items if isinstance(r, dict) and "name" in r]


def _rovers_of(session_path: Path) -> tuple[list[str], int]:
    from rig.core.topics import gnss_time
    from rig.data import load_session

    times = {gnss_time(r) for r in _receiver_names(session_path)}
    ds = load_session(session_path, topics=times)
    receivers = ds.config.get("receivers", [])
    items = receivers.values() if isinstance(receivers, dict) else receivers
    rovers = [str(r["name"]) for r in items if isinstance(r, dict) and r.get("role") == "rover" and "name" in r]
    leap = ds.leap_seconds
    if leap is None:
        raise AnalysisError(f"{session_path}: no TIME log with the leap-second count: log TIMEB on a rover")
    return rovers, int(leap)


def run_ppk(
    session_path: Path | str,
    *,
    rovers: Sequence[str] | None = None,
    out: Path | str | None = None,
    work_dir: Path | str | None = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    elevation_mask_deg: float = ELEVATION_MASK_DEG,
    base: Path | str | None = None,
    systems: Sequence[str] | None = None,
) -> PpkRun:
    """Run RTKLIB on each rover of a recorded session and write the side file (see the module docstring).

    ``work_dir`` keeps the intermediate files (exported streams, RINEX, ``.pos``); default: a temporary
    directory removed afterwards. ``base``: the base's own observations (RINEX 3 obs, or an RTCM3 file with
    1005/1006) instead of the recorded relayed corrections, for a dropout of the link that fed the relay
    itself (the base's internal log, or a reference station's file). ``systems``: RINEX letters of the satellite
    systems to solve with; None: :data:`SYSTEMS` (GPS and GLONASS), each used per rover where the session has
    its observations and ephemerides, a missing one a warning (:attr:`PpkRun.warnings`). Given explicitly
    (``("G", "R")``, ``("G",)`` for GPS only), a system that no rover can use is an error instead; one that only
    some rovers lack is a warning, and those rovers are solved without it.

    Raises:
        RtklibMissingError: ``convbin`` / ``rnx2rtkp`` not on PATH.
        AnalysisError: a rover without RANGECMP or GPSEPHEM logs (the message says what to log), a system asked
            for explicitly that no rover can use, no base position in the corrections, an unknown rover or
            satellite system, or an RTKLIB call that failed or timed out.
        SessionFileError: the session cannot be read or the side file cannot be written.
    """
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq

    from rig.export.files import ExportKind
    from rig.export.raw_gnss import export_raw_gnss

    explicit = systems is not None
    asked = tuple(dict.fromkeys(systems)) if systems is not None else SYSTEMS
    bad = [s for s in asked if s not in _NAVSYS]
    if bad or not asked:
        raise AnalysisError(f"unknown satellite system {', '.join(bad) or '(none given)'}: use the RINEX letters "
                            f"{', '.join(SYSTEM_NAMES)}")
    other = [s for s in asked if s not in SYSTEM_NAMES]
    if other:
        raise AnalysisError(f"satellite system {', '.join(f'{s} ({_OTHER_SYSTEMS[s]})' for s in other)} is not "
                            "supported by rig ppk: it writes navigation data from GPSEPHEMB (G) and GLOEPHEMERISB (R) "
                            "only")
    tools = _tools()
    session = Path(session_path)
    known, leap = _rovers_of(session)
    chosen = list(rovers) if rovers else known
    unknown = [r for r in chosen if r not in known]
    if unknown:
        raise AnalysisError(f"{session}: no rover named {', '.join(unknown)} (rovers: {', '.join(known) or 'none'})")
    if not chosen:
        raise AnalysisError(f"{session}: the session configuration has no rover receiver")
    target = Path(out) if out is not None else ppk_file_path(session)
    if base is not None:
        base = Path(base)
        if not base.is_file():
            raise SessionFileError(f"{base}: no such base observation file (--base)")
    with tempfile.TemporaryDirectory(prefix="rig-ppk-") as tmp:
        wd = Path(work_dir) if work_dir is not None else Path(tmp)
        wd.mkdir(parents=True, exist_ok=True)
        report = export_raw_gnss(session, wd / "raw", overwrite=True)
        warnings = list(report.warnings)
        corrections = [base] if base is not None else [
            f.path for f in report.files if f.kind is ExportKind.CORRECTIONS]
        if not corrections:
            raise AnalysisError(f"{session}: no relayed corrections (/relay/raw) recorded: PPK needs the base's RTCM3 "
                                "(or give the base's own observations with --base FILE)")
        streams = {r: _scan_rover(wd / "raw" / f"{r}.gps", r) if (wd / "raw" / f"{r}.gps").exists() else None
                   for r in chosen}
        lacking: dict[str, list[str]] = {}
        for r, st in streams.items():
            todo = []
            if st is None or st.rangecmp == 0:
                todo.append("RANGECMPB ONTIME 0.05")
            if "G" in asked and (st is None or not st.ephemerides):
                todo.append("GPSEPHEMB ONCHANGED")
            if todo:
                lacking[r] = todo
        if lacking:
            what = "; ".join(f"rover {r} has no {' and no '.join(t.split()[0] for t in todo)}"
                             for r, todo in lacking.items())
            logs = "; ".join(f"log {' and '.join(todo)} on {r}" for r, todo in lacking.items())
            head = ("no raw observations (RANGECMPB) from any rover, nothing to post-process: "
                    if len(chosen) > 1 and all(st is None or st.rangecmp == 0 for st in streams.values()) else "")
            raise AnalysisError(f"{session}: {head}{what} in the recording: {logs} (raw observations and ephemerides)")
        first = min(st.first_gps_ns for st in streams.values() if st is not None and st.first_gps_ns is not None)
        t_approx = _GPS_EPOCH + dt.timedelta(microseconds=first // 1000)
        if _is_rinex_obs(corrections[0]):
            base_obs = corrections[0]
        else:
            base_obs = wd / "base.obs"
            _run([tools["convbin"], "-r", "rtcm3", "-v", "3.04", "-tr",
                  *t_approx.strftime("%Y/%m/%d %H:%M:%S").split(), "-o", str(base_obs), str(corrections[0])],
                 "base corrections to RINEX", timeout_s, wd)
        base_xyz = _approx_position(base_obs) if base_obs.exists() else None
        if base_xyz is None:
            raise AnalysisError(f"{corrections[0]}: no base position (RTCM 1005/1006, or a RINEX APPROX POSITION XYZ): "
                                "log RTCM1006 on the base")
        base_systems = _rinex_obs_systems(base_obs, asked)
        # each rover's systems, decided before anything is solved
        plan: dict[str, tuple[str, ...]] = {}
        for r in chosen:
            st = streams[r]
            assert st is not None
            obs = wd / f"{r}.obs"
            _run([tools["convbin"], "-r", "nov", "-v", "3.04", "-o", str(obs), str(wd / "raw" / f"{r}.gps")],
                 f"rover {r} to RINEX", timeout_s, wd)
            eph = {"G"} if st.ephemerides else set()
            if st.glonass:
                eph.add("R")
            used, notes = usable_systems(r, asked, rover_obs=_rinex_obs_systems(obs, asked), ephemerides=eph,
                                         base_obs=base_systems)
            plan[r] = used
            warnings.extend(notes)
        nowhere = [s for s in asked if not any(s in used for used in plan.values())]
        stuck = [r for r, used in plan.items() if not used]
        if (explicit and nowhere) or stuck:
            names = [SYSTEM_NAMES[s] for s in nowhere]
            lost = f"{' and '.join(names)} asked for (--systems {','.join(asked)}) but usable for no rover" if (
                explicit and nowhere) else f"no satellite system to solve {', '.join(stuck)} with"
            rest = [s for s in asked if s not in nowhere]
            hint = f"; solve without it: --systems {','.join(rest)}" if explicit and nowhere and rest else ""
            raise AnalysisError(f"{session}: {lost}: {'; '.join(w for w in warnings if w not in report.warnings)}"
                                f"{hint}")
        tables = []
        results = []
        for r in chosen:
            st = streams[r]
            assert st is not None
            used = plan[r]
            conf = wd / f"{r}.conf"
            # -k resets the output options to the options file's defaults: keep rnx2rtkp's own (GPS week + TOW)
            conf.write_text(f"pos1-navsys       ={sum(_NAVSYS[s] for s in used)}\n"
                            "pos2-gloarmode    =on\n"
                            "out-timeform      =tow\n"
                            "out-timendec      =3\n")
            nav = wd / f"{r}.nav"
            glo = st.glonass if "R" in used else ()
            write_rinex_nav(st.ephemerides if "G" in used else (), nav, glo)
            obs = wd / f"{r}.obs"
            pos = wd / f"{r}.pos"
            _run([tools["rnx2rtkp"], "-k", str(conf), "-p", "2", "-c", "-f", "2", "-m", f"{elevation_mask_deg:g}",
                  "-sys", ",".join(used),
                  "-r", *(f"{v:.4f}" for v in base_xyz), "-o", str(pos), str(obs), str(base_obs), str(nav)],
                 f"rover {r} PPK", timeout_s, wd)
            rows = _read_pos(pos)
            # integer arithmetic: GPS ns since 1980 need 61 bits, more than a float's mantissa
            gps_ns = rows[:, 0].astype(np.int64) * _WEEK_NS + np.round(rows[:, 1] * 1000.0).astype(np.int64) * 1_000_000
            q = rows[:, 5].astype(np.int8)
            tables.append(pa.table({
                "rover": pa.array([r] * len(rows), pa.string()),
                "gps_time_ns": gps_ns,
                "time_ns": gps_ns + _GPS_UNIX_OFFSET_NS - leap * _NS,
                "lat_deg": rows[:, 2], "lon_deg": rows[:, 3], "height_m": rows[:, 4],
                "q": q, "ns": rows[:, 6].astype(np.int16),
                "sdn_m": rows[:, 7], "sde_m": rows[:, 8], "sdu_m": rows[:, 9], "ratio": rows[:, 14],
            }))
            results.append(PpkRover(r, len(rows), int(np.count_nonzero(q == PpkQuality.FIX)), st.rangecmp,
                                    float(np.median(rows[:, 6])) if len(rows) else 0.0, len(glo), used))
        meta = {"systems_asked": list(asked), "systems_explicit": explicit,
                "rovers": {p.rover: {"systems": list(p.systems), "glonass_ephemerides": p.glonass_ephemerides}
                           for p in results},
                "warnings": warnings}
        table = pa.concat_tables(tables)
        table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                               PPK_METADATA_KEY: json.dumps(meta).encode()})
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp_out = target.with_name(target.name + ".tmp")
            pq.write_table(table, tmp_out)
            tmp_out.replace(target)
        except OSError as exc:
            raise SessionFileError(f"{target}: cannot write the PPK side file: {exc}") from exc
    return PpkRun(target, tuple(results), tuple(warnings))


