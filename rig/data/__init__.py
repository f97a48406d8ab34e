"""Reading recorded sessions into time-aligned numpy arrays: the only way analysis code reads files.

    from rig.data import load_session
    s = load_session("sessions/run1")          # all parts, in order
    g = s.gnss("rover_a"); g.bestpos["lat_deg"], g.bestpos.time_ns, g.bestpos.valid
    roles = s.can_roles("vehicle")             # {role: RoleSeries} via the vectorised decoder
    d = s.daq("daq1", sync_channel="sync", receiver="rover_a")
    t, opt = s.optical("s350_body", spec)      # from the DAQ, or from /optical/<sensor> without spec
    tr = s.truth()                              # simulated sessions
"""

from rig.data.session import (
    CanFrames,
    DaqData,
    DaqSegment,
    GnssData,
    Session,
    Table,
    Truth,
    align,
    load_session,
)

__all__ = ["CanFrames", "DaqData", "DaqSegment", "GnssData", "Session", "Table", "Truth", "align", "load_session"]
