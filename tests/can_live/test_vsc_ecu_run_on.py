"""The simulated ECU running on past the drive: the car in its last state, until the ECU is stopped."""

from __future__ import annotations

import math
from collections import defaultdict

import can
import cantools
import numpy as np
import pytest

import sim_devices.vsc_ecu as vsc_ecu
from sim_devices.vsc_ecu import VscEcu, frames, simulate_ecu, vsc_sim_dbc_path
from tests.can_live.truth_builders import steady_circle
from vsccore.clock import ScaledClock
from vsccore.errors import SimulationError

DEG = math.pi / 180.0
KMH = 1.0 / 3.6


def test_past_the_truth_the_car_stands_where_the_drive_ended() -> None:
    """As the simulated receivers show it (position and attitude held, no motion): a CAN stream that said
    otherwise would pull the GNSS reference's yaw-rate bias at the end of every recording."""
    truth = steady_circle(15.0, 100.0, 2.0)
    drive = simulate_ecu(truth)
    on = simulate_ecu(truth, t_end_s=5.0)
    assert drive.t_end_s == pytest.approx(2.0) and on.t_end_s == 5.0
    for name, series in drive.messages.items():
        longer = on.messages[name]
        n = series.t.size
        period = float(np.median(np.diff(series.t)))
        assert longer.t.size == pytest.approx(n + 3.0 / period, abs=1)
        np.testing.assert_array_equal(longer.t[:n], series.t)  # a longer run-on appends frames
        assert np.diff(longer.t).max() < 1.5 * period
        inside = series.t < 1.99  # (the last truth sample's derivatives change once there are samples after it)
        for signal, values in series.signals.items():
            if not signal.startswith("ESC_WheelPressure_"):  # (their noise is drawn per wheel, not per time)
                np.testing.assert_array_equal(longer.signals[signal][:n][inside], values[inside],
                                              err_msg=f"{name}.{signal}")
    cfg_bias = 0.25 * DEG
    sc = on.messages["ESC_SensorCluster"]
    after = sc.t > 2.1
    # standing: the yaw-rate sensor reads its bias, the lateral accelerometer the roll's gravity component
    assert np.mean(sc.signals["ESC_YawRate"][after]) * DEG == pytest.approx(cfg_bias, abs=0.02 * DEG)
    roll_g = 9.80665 * math.sin(float(truth.roll[-1]))
    assert np.mean(sc.signals["ESC_LatAccel"][after]) * 9.80665 == pytest.approx(roll_g + 0.05, abs=0.02)
    # the wheels stand: the edge timing reads the last speed until its 0.2 s timeout, then 0
    ws = on.messages["ESC_WheelSpeeds"]
    for wheel in ("FL", "FR", "RL", "RR"):
        kmh = ws.signals[f"ESC_WheelSpeed_{wheel}"]
        assert np.all(kmh[ws.t > 2.25] == 0.0) and kmh[ws.t < 2.0][-1] * KMH == pytest.approx(15.0, rel=0.03)
    sas = on.messages["SAS_Steering"]
    assert np.all(sas.signals["SAS_Angle"][sas.t > 2.1] == sas.signals["SAS_Angle"][sas.t <= 2.0][-1])  # held
    with pytest.raises(SimulationError, match="before the truth's end"):
        simulate_ecu(truth, t_end_s=1.0)


def test_a_running_on_ecu_sends_the_same_frames_across_its_stretches_until_stopped(
    channel: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Past the outputs it was given, the ECU computes the next stretch (here 0.5 s, then as far again):
    the frames go on at their periods with their rolling counters, as one computation to the end gives."""
    monkeypatch.setattr(vsc_ecu, "RUN_ON_STRETCH_S", 0.5)
    db = cantools.database.load_file(vsc_sim_dbc_path())
    truth = steady_circle(15.0, 100.0, 1.0)
    outputs = simulate_ecu(truth, t_end_s=1.5)  # first stretch computed before the clock starts
    until_s = 2.9  # into the third stretch (1.5 → 2.0 → 3.0)
    expected = [(t, m.arbitration_id, bytes(m.data))
                for t, m in frames(truth, outputs=simulate_ecu(truth, t_end_s=3.0)) if t <= until_s]
    t0_ns = 1_700_000_000_000_000_000
    clock = ScaledClock(t0_ns - 200_000_000, speed=5.0)
    got: list[can.Message] = []
    with (
        can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as ecu_bus,
        can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as rx,
    ):
        ecu = VscEcu(truth, ecu_bus, clock, t0_ns, outputs=outputs, max_lag_s=60.0, run_on=True)
        with ecu:
            while len(got) < len(expected):
                msg = rx.recv(timeout=10.0)
                assert msg is not None, f"the ECU stopped sending after {len(got)} of {len(expected)} frames"
                got.append(msg)
            assert not ecu.finished.is_set()  # still running on
        assert ecu.finished.is_set() and ecu.failure is None
    assert ecu.frames_skipped == 0
    brake = db.get_message_by_name("ESC_BrakePressure").frame_id
    assert [m.arbitration_id for m in got] == [i for _, i, _ in expected]
    for m, (t, frame_id, data) in zip(got, expected, strict=True):
        assert m.timestamp == pytest.approx((t0_ns + t * 1e9) / 1e9, abs=1e-6)
        if frame_id != brake:  # (wheel pressures' noise differs per computation; counter and CRC checked below)
            assert bytes(m.data) == data, f"{frame_id:#x} at {t:.3f} s"
    counters: dict[int, list[int]] = defaultdict(list)
    for m in got:
        decoded = db.decode_message(m.arbitration_id, bytes(m.data), decode_choices=False)
        if "COUNTER" in decoded:
            counters[m.arbitration_id].append(int(decoded["COUNTER"]))
    assert brake in counters
    for frame_id, seq in counters.items():
        assert all((b - a) % 16 == 1 for a, b in zip(seq, seq[1:], strict=False)), f"{frame_id:#x} counter"
