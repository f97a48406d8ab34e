"""The files a session keeps beside its parts: the calibration results (``<session>.calibration.json``) and the
PPK solutions (``<session>.ppk.parquet``)."""


from __future__ import annotations

import datetime as dt
import json
import os
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from pydantic import ValidationError

from rig.core.config import CalibrationConfig, ImuCalibrationConfig
from rig.store.reader import find_parts, session_base
from vsccore.errors import ConfigError, SessionFileError

__all__ = [
    "CALIBRATION_FILE_FORMAT",
    "PPK_COLUMNS",
    "PPK_METADATA_KEY",
    "PpkQuality",
    "PpkSolutions",
    "apply_calibration_file",
    "calibration_file_path",
    "ppk_file_path",
    "ppk_metadata",
    "read_calibration_file",
    "read_ppk_file",
    "update_calibration_file",
]

PPK_METADATA_KEY = b"rig.ppk"
"""Parquet key-value metadata of the side file: JSON with the systems asked for, each rover's systems used and
GLONASS set count, and the warnings of the run."""


PPK_COLUMNS = ("rover", "gps_time_ns", "time_ns", "lat_deg", "lon_deg", "height_m", "q", "ns",
               "sdn_m", "sde_m", "sdu_m", "ratio")
"""Columns of the side file: GPS time (ns since the GPS epoch), UTC (ns since the Unix epoch, with the
session's leap seconds), WGS84 latitude/longitude (deg) and ellipsoidal height, RTKLIB's quality flag
``q`` (:class:`PpkQuality`), satellites, standard deviations (m) and the ambiguity ratio."""


def ppk_file_path(session_path: Path | str) -> Path:
    """``<session base>.ppk.parquet`` (next to the parts ``<base>.NNN.mcap``)."""
    from rig.store import find_parts, session_base

    p = Path(session_path)
    try:
        base = session_base(find_parts(p)[0])
    except SessionFileError:
        base = session_base(p)
    return base.with_name(f"{base.name}.ppk.parquet")


@dataclass(frozen=True, slots=True)
class PpkSolutions:
    """One rover's PPK solutions from the side file (arrays in epoch order)."""

    rover: str
    gps_time_ns: npt.NDArray[np.int64]
    lat_deg: npt.NDArray[np.float64]
    lon_deg: npt.NDArray[np.float64]
    height_m: npt.NDArray[np.float64]
    q: npt.NDArray[np.int8]
    sdn_m: npt.NDArray[np.float64]
    sde_m: npt.NDArray[np.float64]
    sdu_m: npt.NDArray[np.float64]
    ratio: npt.NDArray[np.float64]
    systems: tuple[str, ...] = ()
    """The satellite systems this rover was solved with (from the side file's metadata; () in files written
    before it was recorded)."""

    @property
    def fixed(self) -> npt.NDArray[np.bool_]:
        return np.asarray(self.q == PpkQuality.FIX)


def read_ppk_file(path: Path | str) -> dict[str, PpkSolutions]:
    """The side file's solutions per rover ({} when there is no file).

    Raises:
        SessionFileError: the file exists but is not a readable PPK side file (columns named).
    """
    import pyarrow.parquet as pq

    p = Path(path)
    if not p.exists():
        return {}
    try:
        tbl = pq.read_table(p)
    except (OSError, ValueError) as exc:
        raise SessionFileError(f"{p}: not a readable PPK side file: {exc}") from exc
    missing = [c for c in PPK_COLUMNS if c not in tbl.column_names]
    if missing:
        raise SessionFileError(f"{p}: PPK side file lacks the columns {', '.join(missing)}")
    rovers_meta = ppk_metadata(tbl.schema.metadata, p).get("rovers", {})
    used = {str(r): tuple(str(s) for s in v.get("systems", ())) for r, v in rovers_meta.items()
            if isinstance(v, dict)} if isinstance(rovers_meta, dict) else {}
    cols = {c: tbl.column(c).to_numpy() for c in PPK_COLUMNS}
    out: dict[str, PpkSolutions] = {}
    for r in sorted(set(cols["rover"].tolist())):
        m = cols["rover"] == r
        idx = np.flatnonzero(m)[np.argsort(cols["gps_time_ns"][m], kind="stable")]

        def col(name: str, dtype: type, idx: npt.NDArray[np.intp] = idx) -> npt.NDArray:
            return np.asarray(cols[name][idx], dtype=dtype)

        out[str(r)] = PpkSolutions(str(r), col("gps_time_ns", np.int64), col("lat_deg", np.float64),
                                   col("lon_deg", np.float64), col("height_m", np.float64), col("q", np.int8),
                                   col("sdn_m", np.float64), col("sde_m", np.float64), col("sdu_m", np.float64),
                                   col("ratio", np.float64), used.get(str(r), ()))
    return out


def ppk_metadata(metadata: dict[bytes, bytes] | None, path: Path | str = "side file") -> dict[str, Any]:
    """The side file's ``rig.ppk`` metadata (:data:`PPK_METADATA_KEY`) as a dict ({} when the file has none:
    written before the systems were recorded).

    Raises:
        SessionFileError: the metadata is not a JSON object.
    """
    import json

    raw = (metadata or {}).get(PPK_METADATA_KEY)
    if raw is None:
        return {}
    try:
        meta = json.loads(raw)
    except ValueError as exc:
        raise SessionFileError(f"{path}: unreadable {PPK_METADATA_KEY.decode()} metadata: {exc}") from exc
    if not isinstance(meta, dict):
        raise SessionFileError(f"{path}: {PPK_METADATA_KEY.decode()} metadata is not a JSON object")
    return meta


CALIBRATION_FILE_FORMAT = "vsc_rig.calibration/1"


def calibration_file_path(session_path: Path | str) -> Path:
    """``<session base>.calibration.json`` (next to the parts ``<base>.NNN.mcap``)."""
    p = Path(session_path)
    try:
        parts = find_parts(p)
        base = session_base(parts[0])
    except SessionFileError:
        base = session_base(p)
    return base.with_name(f"{base.name}.calibration.json")


def read_calibration_file(session_path: Path | str) -> dict[str, Any]:
    """The session's calibration results (``{}`` when there is no file).

    Raises:
        SessionFileError: the file exists but is not a readable calibration file.
    """
    path = calibration_file_path(session_path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return {}
    except OSError as exc:
        raise SessionFileError(f"{path}: cannot read the calibration file: {exc.strerror}") from exc
    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise SessionFileError(f"{path}: not a JSON calibration file ({exc})") from exc
    if not isinstance(doc, dict) or doc.get("format") != CALIBRATION_FILE_FORMAT:
        raise SessionFileError(f"{path}: not a {CALIBRATION_FILE_FORMAT} calibration file")
    return doc


def update_calibration_file(session_path: Path | str, key: str, result: Mapping[str, Any]) -> Path:
    """Record ``result`` under ``results.<key>`` of the session's calibration file (atomically); returns the path.

    Keys used by the commands: ``mount_offset`` (offset_deg, u95_deg, …), ``optical_zero``
    ({sensor: {zero_deg, u95_deg, …}}), ``steering_ratio`` (rows), ``imu`` (accel/gyro matrices).
    """
    path = calibration_file_path(session_path)
    doc = read_calibration_file(session_path) or {"format": CALIBRATION_FILE_FORMAT,
                                                 "session": session_base(path.with_name(path.name.removesuffix(
                                                     ".calibration.json"))).name, "results": {}}
    results = doc.setdefault("results", {})
    entry = dict(result)
    entry.setdefault("recorded_at", dt.datetime.now(dt.UTC).isoformat(timespec="seconds"))
    results[key] = entry
    text = json.dumps(doc, indent=2, sort_keys=False, allow_nan=False, default=_json_default)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text + "\n")
        Path(tmp).replace(path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise SessionFileError(f"{path}: cannot write the calibration file: {exc.strerror}") from exc
    return path


def _json_default(obj: object) -> object:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON-serialisable: {type(obj).__name__}")


def apply_calibration_file(cal: CalibrationConfig, doc: Mapping[str, Any]) -> tuple[CalibrationConfig, list[str]]:
    """The calibration in force with the results of a calibration file applied; (calibration, what was applied)."""
    res = doc.get("results", {}) if isinstance(doc, Mapping) else {}
    upd: dict[str, Any] = {}
    applied: list[str] = []
    m = res.get("mount_offset")
    if isinstance(m, Mapping) and isinstance(m.get("offset_deg"), int | float):
        upd.update(mount_offset_deg=float(m["offset_deg"]), mount_offset_u95_deg=m.get("u95_deg"),
                   mount_offset_date=m.get("date"), mount_offset_session=m.get("session"))
        applied.append("mount_offset")
    z = res.get("optical_zero")
    if isinstance(z, Mapping):
        zeros = dict(cal.optical_zero_deg)
        for name, v in z.items():
            if isinstance(v, Mapping) and isinstance(v.get("zero_deg"), int | float) and name != "recorded_at":
                zeros[str(name)] = float(v["zero_deg"])
        if zeros != dict(cal.optical_zero_deg):
            upd["optical_zero_deg"] = zeros
            applied.append("optical_zero")
    s = res.get("steering_ratio")
    if (isinstance(s, Mapping) and isinstance(s.get("swa_deg"), list) and isinstance(s.get("ratio"), list)
            and s["swa_deg"] and len(s["swa_deg"]) == len(s["ratio"])):
        upd.update(steering_ratio_swa_deg=tuple(float(x) for x in s["swa_deg"]),
                   steering_ratio=tuple(float(x) for x in s["ratio"]), steering_ratio_date=s.get("date"))
        applied.append("steering_ratio")
    z = s.get("sas_zero") if isinstance(s, Mapping) else None
    if isinstance(z, Mapping) and isinstance(z.get("offset_deg"), int | float):
        upd.update(swa_zero_offset_deg=float(z["offset_deg"]), swa_zero_offset_u95_deg=z.get("u95_deg"))
        applied.append("sas_zero")
    imu = res.get("imu")
    if isinstance(imu, Mapping) and isinstance(imu.get("config"), Mapping):
        try:
            upd["imu"] = ImuCalibrationConfig.model_validate(imu["config"])
            applied.append("imu")
        except ValidationError as exc:
            raise ConfigError(f"calibration file: results.imu.config is invalid: {exc}") from None
    if not upd:
        return cal, applied
    try:
        return CalibrationConfig.model_validate({**cal.model_dump(), **{k: (v.model_dump() if hasattr(
            v, "model_dump") else v) for k, v in upd.items()}}), applied
    except ValidationError as exc:
        raise ConfigError(f"calibration file: results do not form a valid calibration: {exc}") from None


class PpkQuality:
    """RTKLIB's solution quality flag (``Q`` of a ``.pos`` file)."""

    FIX = 1
    FLOAT = 2
    SBAS = 3
    DGPS = 4
    SINGLE = 5
    PPP = 6
