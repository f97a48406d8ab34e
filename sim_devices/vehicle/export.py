"""Ground truth as a flat table with unit-suffixed column names, and its CSV / Parquet files.

The files are for engineers who load them into MATLAB or pandas: one row per sample, the columns
of :data:`COLUMNS`, full double precision. Parquet files also carry the drive's metadata (scenario,
parameters, ENU origin) as key/value metadata.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from sim_devices.vehicle.geodesy import point_geodetic
from sim_devices.vehicle.truth import WHEELS, GroundTruth
from vsccore.errors import SessionFileError, SimulationError

__all__ = ["COLUMNS", "TRUTH_FILE_SUFFIXES", "truth_columns", "truth_table", "write_truth"]

TRUTH_FILE_SUFFIXES = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet"}
"""File name endings :func:`write_truth` understands and the format each selects."""

FloatArray = npt.NDArray[np.float64]

COLUMNS: tuple[str, ...] = (
    "t_s",
    "east_m",
    "north_m",
    "lat_deg",
    "lon_deg",
    "height_m",
    "heading_deg",
    "yaw_deg",
    "speed_mps",
    "vx_mps",
    "vy_mps",
    "yaw_rate_dps",
    "ax_mps2",
    "ay_mps2",
    "ax_meas_mps2",
    "ay_meas_mps2",
    "roll_deg",
    "beta_cg_deg",
    "swa_deg",
    "road_wheel_deg",
    *(f"wheel_speed_{w}_mps" for w in WHEELS),
    *(f"fz_{w}_n" for w in WHEELS),
    "ltr",
)
"""Column names in file order. heading_deg is the azimuth clockwise from north in [0, 360); yaw_deg is
counter-clockwise from east, unwrapped; lat/lon/height (WGS 84 ellipsoidal) are those of the CG."""


def truth_columns(truth: GroundTruth) -> dict[str, FloatArray]:
    """The ground truth as ordered columns named in :data:`COLUMNS` (degrees where the name says so)."""
    lat, lon, height = point_geodetic(truth)
    deg = np.degrees
    cols: dict[str, FloatArray] = {
        "t_s": truth.t,
        "east_m": truth.east,
        "north_m": truth.north,
        "lat_deg": lat,
        "lon_deg": lon,
        "height_m": height,
        "heading_deg": deg(truth.heading_azimuth),
        "yaw_deg": deg(truth.yaw),
        "speed_mps": truth.speed,
        "vx_mps": truth.vx,
        "vy_mps": truth.vy,
        "yaw_rate_dps": deg(truth.yaw_rate),
        "ax_mps2": truth.ax,
        "ay_mps2": truth.ay,
        "ax_meas_mps2": truth.ax_meas,
        "ay_meas_mps2": truth.ay_meas,
        "roll_deg": deg(truth.roll),
        "beta_cg_deg": deg(truth.beta_cg),
        "swa_deg": deg(truth.swa),
        "road_wheel_deg": deg(truth.road_wheel_angle),
    }
    for j, w in enumerate(WHEELS):
        cols[f"wheel_speed_{w}_mps"] = truth.wheel_speed[:, j]
    for j, w in enumerate(WHEELS):
        cols[f"fz_{w}_n"] = truth.wheel_load[:, j]
    cols["ltr"] = truth.ltr
    return {name: np.asarray(cols[name], dtype=np.float64) for name in COLUMNS}


def truth_table(truth: GroundTruth) -> pa.Table:
    """The ground truth as a pyarrow table (columns of :data:`COLUMNS`, float64)."""
    cols = truth_columns(truth)
    return pa.table({name: pa.array(values, type=pa.float64()) for name, values in cols.items()})


def write_truth(truth: GroundTruth, path: str | Path) -> Path:
    """Write the ground truth to ``path`` as CSV (``.csv``) or Parquet (``.parquet``, ``.pq``).

    Raises SimulationError for another file ending and SessionFileError when the file cannot be
    written (both name the file).
    """
    p = Path(path)
    fmt = TRUTH_FILE_SUFFIXES.get(p.suffix.lower())
    if fmt is None:
        raise SimulationError(
            f"{p}: unknown output format {p.suffix or '(no ending)'!r}; use one of {', '.join(TRUTH_FILE_SUFFIXES)}"
        )
    table = truth_table(truth)
    try:
        if fmt == "csv":
            # Header written by hand: plain names (pyarrow quotes header names), which MATLAB reads cleanly.
            with p.open("wb") as f:
                f.write((",".join(table.column_names) + "\n").encode("ascii"))
                options = pa_csv.WriteOptions(include_header=False, quoting_style="none")
                pa_csv.write_csv(table, f, write_options=options)
        else:
            meta = {
                "vsc_rig.meta": json.dumps(truth.meta),
                "vsc_rig.origin": json.dumps({"lat_deg": truth.lat0_deg, "lon_deg": truth.lon0_deg, "h_m": truth.h0_m}),
            }
            pq.write_table(table.replace_schema_metadata(meta), str(p))
    except (OSError, pa.ArrowException) as exc:
        raise SessionFileError(f"{p}: cannot write the ground truth ({exc})") from exc
    return p
