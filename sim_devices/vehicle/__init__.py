"""Vehicle-dynamics model, tyre model, scenarios and the ground truth they produce.

Typical use::

    from sim_devices.vehicle import Drive, make_scenario, simulate

    drive = Drive([make_scenario("straight", heading_deg=0), make_scenario("straight", heading_deg=180),
                   make_scenario("steady_state_circle"), make_scenario("double_lane_change"),
                   make_scenario("j_turn")], gap_s=5.0)
    truth = simulate(drive)          # GroundTruth at 1 kHz
"""

from sim_devices.vehicle.export import COLUMNS, TRUTH_FILE_SUFFIXES, truth_columns, truth_table, write_truth
from sim_devices.vehicle.geodesy import point_enu_rolled, point_geodetic
from sim_devices.vehicle.params import GRAVITY, VehicleParams, load_vehicle_toml
from sim_devices.vehicle.scenarios import (
    SCENARIOS,
    Drive,
    ParamSpec,
    Scenario,
    ScenarioSpec,
    demo_drive,
    iso3888_1_course,
    make_scenario,
    swa_circle_values_deg,
)
from sim_devices.vehicle.simulate import DEFAULT_ORIGIN, simulate
from sim_devices.vehicle.steering import SteeringGear
from sim_devices.vehicle.truth import WHEELS, GroundTruth

__all__ = [
    "COLUMNS",
    "DEFAULT_ORIGIN",
    "GRAVITY",
    "SCENARIOS",
    "TRUTH_FILE_SUFFIXES",
    "WHEELS",
    "Drive",
    "GroundTruth",
    "ParamSpec",
    "Scenario",
    "ScenarioSpec",
    "SteeringGear",
    "VehicleParams",
    "demo_drive",
    "iso3888_1_course",
    "load_vehicle_toml",
    "make_scenario",
    "point_enu_rolled",
    "point_geodetic",
    "simulate",
    "swa_circle_values_deg",
    "truth_columns",
    "truth_table",
    "write_truth",
]
