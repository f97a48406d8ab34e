"""A short simulated drive that validates (dual-antenna RTK, the VSC's CAN bus with an interface clock):
a 4 s straight and a double lane change at 50 km/h, recorded at 2.5x on the governed clock."""

from __future__ import annotations

from pathlib import Path


def record_validating_drive(out: Path) -> Path:
    """Record the drive under ``out``; the session's path (``out/run``)."""
    from rig.core.config import load_session as load_config
    from rig.sim.record import record_simulated
    from rig.workflows.demo import demo_config_path
    from sim_devices.vehicle import Drive, VehicleParams, make_scenario, simulate
    from tests.validate_cli.conftest import FAST_RTK

    cfg = load_config(demo_config_path(), {"simulation.gnss.position_noise_m": 0.01,
                                            "simulation.true_mount_offset_deg": 0.0})
    sim = cfg.simulation
    assert sim is not None
    plan = Drive([make_scenario("straight", speed_kmh=50.0, duration_s=4.0),
                  make_scenario("double_lane_change", speed_kmh=50.0)], gap_s=2.0)
    truth = simulate(plan, VehicleParams.from_mapping(cfg.profile.vehicle.model_dump()), rate_hz=1000.0,
                     origin=(sim.origin_lat_deg, sim.origin_lon_deg, sim.origin_h_m),
                     initial_heading_deg=sim.initial_heading_deg, seed=sim.seed)
    rec = record_simulated(cfg, out, name="run", drive=plan, truth=truth, speed=2.5, rtk=FAST_RTK,
                           config_path=demo_config_path())
    assert rec.completed
    return out / "run"
