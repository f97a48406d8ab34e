"""EGM96 geoid height of a simulated receiver's site: what its factory ``UNDULATION EGM96`` reports.

The grid (``egm96_1deg.json`` beside this module) holds NGA's EGM96 geoid heights at whole degrees,
taken from PROJ's ``egm96_15.gtx`` (the 15′ grid, public domain); it is interpolated bilinearly. A
receiver's own table is 0.5° (OEM7 Commands and Logs Reference, UNDULATION); the 1° grid is within
0.4 m rms of the 15′ grid (Stuttgart 48.26 m against 48.55 m), a few metres in high mountains.
"""

from __future__ import annotations

import base64
import functools
import json
import math
import zlib
from importlib import resources

import numpy as np
import numpy.typing as npt

__all__ = ["egm96_undulation_m"]


@functools.cache
def _grid() -> tuple[float, float, float, npt.NDArray[np.float64]]:
    doc = json.loads(resources.files(__package__).joinpath("egm96_1deg.json").read_text(encoding="ascii"))
    raw = np.frombuffer(zlib.decompress(base64.b64decode(doc["data"])), dtype="<i2")
    deltas = raw.astype(np.int32).reshape(int(doc["rows"]), int(doc["cols"]))
    heights = (np.cumsum(deltas, axis=1) * float(doc["unit_m"])).astype(np.float64)
    return float(doc["lat0_deg"]), float(doc["lon0_deg"]), float(doc["step_deg"]), heights


def egm96_undulation_m(lat_deg: float, lon_deg: float) -> float:
    """EGM96 geoid height (m above the WGS 84 ellipsoid) at a position: ellipsoidal h = MSL H + N."""
    if not (math.isfinite(lat_deg) and math.isfinite(lon_deg) and -90.0 <= lat_deg <= 90.0):
        raise ValueError(f"EGM96: position ({lat_deg}, {lon_deg}) is not a latitude/longitude in degrees")
    lat0, lon0, step, n = _grid()
    rows, cols = n.shape
    r = (lat_deg - lat0) / step
    c = ((lon_deg - lon0) % 360.0) / step
    r0 = min(int(r), rows - 2)
    c0 = int(c) % cols
    fr, fc = r - r0, c - int(c)
    c1 = (c0 + 1) % cols  # the grid wraps at ±180°
    south = (1.0 - fc) * n[r0, c0] + fc * n[r0, c1]
    north = (1.0 - fc) * n[r0 + 1, c0] + fc * n[r0 + 1, c1]
    return float((1.0 - fr) * south + fr * north)
