"""One solution epoch of a simulated receiver: what its position and velocity logs report."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.novatel import PositionType, SolutionStatus
from sim_devices.gnss.antenna import AntennaState
from sim_devices.gnss.constellation import SatObservation

__all__ = ["Solution"]


@dataclass(frozen=True, slots=True)
class Solution:
    """One solution epoch of a simulated receiver (what BESTPOS, BESTVEL, BESTXYZ … report)."""

    t_gps_ns: int
    pos_type: PositionType
    lat_deg: float
    lon_deg: float
    height_m: float  # ellipsoidal
    sigma_enu_m: tuple[float, float, float]
    vel_enu_mps: tuple[float, float, float]
    vel_sigma_enu_mps: tuple[float, float, float]
    diff_age_s: float
    station_id: str
    satellites: tuple[SatObservation, ...]
    num_soln_svs: int
    truth: AntennaState
    sol_status: SolutionStatus = SolutionStatus.SOL_COMPUTED
    """INSUFFICIENT_OBS while restarting; the integrity monitor's verdict on a fixed position."""
