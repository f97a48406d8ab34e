"""GPS time: (week, seconds of week) ↔ integer nanoseconds since the GPS epoch, and to UTC.

The GPS−UTC offset (leap seconds) always comes from the receiver (NovAtel TIME log, or a value
recorded with the session); it is never a constant in this code.
"""

from __future__ import annotations

NS_PER_S = 1_000_000_000
SECONDS_PER_WEEK = 604_800
NS_PER_WEEK = SECONDS_PER_WEEK * NS_PER_S
#: 1980-01-06T00:00:00Z as nanoseconds since the Unix epoch.
GPS_EPOCH_UNIX_NS = 315_964_800 * NS_PER_S


def gps_to_ns(week: int, seconds_of_week: float) -> int:
    """GPS week and seconds of week → integer ns since the GPS epoch.

    Seconds are rounded to the nearest nanosecond (NovAtel reports milliseconds, so nothing is
    lost).
    """
    if week < 0:
        raise ValueError(f"GPS week must be >= 0, got {week}")
    return week * NS_PER_WEEK + round(seconds_of_week * NS_PER_S)


def ns_to_gps(gps_ns: int) -> tuple[int, float]:
    """Integer ns since the GPS epoch → (week, seconds of week)."""
    week, rem = divmod(gps_ns, NS_PER_WEEK)
    return week, rem / NS_PER_S


def gps_ns_to_unix_ns(gps_ns: int, leap_seconds: int) -> int:
    """GPS ns → UTC as ns since the Unix epoch, with the receiver-reported GPS−UTC offset (s)."""
    return gps_ns + GPS_EPOCH_UNIX_NS - leap_seconds * NS_PER_S


def unix_ns_to_gps_ns(unix_ns: int, leap_seconds: int) -> int:
    """UTC ns since the Unix epoch → GPS ns, with the GPS−UTC offset (s)."""
    return unix_ns - GPS_EPOCH_UNIX_NS + leap_seconds * NS_PER_S
