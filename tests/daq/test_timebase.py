"""The DAQ on GPS time: sync edges from a shared GPS pulse schedule, found live, against the simulator's true times."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import pytest

from drivers.daq import DaqEvent, DaqEventKind, DaqLink, fit_sample_clock
from sim_devices.daq import SimDaqBackend, SyncPulseOutput
from tests.daq.helpers import T0_NS, ManualClock, steady_circle
from vsccore.gpstime import gps_to_ns

RATE = 1000.0
PPM = 30.0  # the SimulationConfig default for the simulated DAQ's sample clock
OFFSET_S = 0.0123  # the first sample is 12.3 ms late against true time
EPOCH_GPS_NS = gps_to_ns(2400, 345600.0)  # GPS time of truth t = 0 (SimulationConfig defaults)


def pulse_schedule(n: int = 9) -> list[int]:
    """Pulse GPS times as a GNSS simulator's sync schedule would give them: irregular, not on round ns."""
    rng = np.random.default_rng(11)
    t_s = 1.0 + np.cumsum(rng.uniform(1.5, 2.5, n))
    return [EPOCH_GPS_NS + int(round(x * 1e9)) + int(rng.integers(0, 1000)) for x in t_s]


def daq_config(sync_threshold_v: float = 2.5) -> dict:
    """A ``[daq]`` table as ``DaqConfig.model_dump()`` gives it."""
    return {
        "backend": "sim",
        "device": "SimDAQ",
        "rate_hz": RATE,
        "block_size": 100,
        "buffer_samples": 10_000,
        "channels": [{"name": "sync", "physical": "ai7", "range_v": (0.0, 10.0), "terminal": "rse"}],
        "sync_channel": "sync",
        "sync_threshold_v": sync_threshold_v,
        "analog": [],
    }


@pytest.fixture(scope="module")
def live_edges() -> tuple[list[DaqEvent], list[int], SimDaqBackend]:
    """Run a DaqLink from the configuration on the simulated DAQ until every pulse was seen."""
    schedule = pulse_schedule()
    truth = steady_circle(duration=22.0)
    options: dict[str, Any] = {
        "truth": truth,
        "sources": {"ai7": SyncPulseOutput.from_gps(schedule, EPOCH_GPS_NS, width_s=0.2, noise_v=0.002)},
        "truth_start_ns": T0_NS,
        "clock_ppm": PPM,
        "clock_offset_s": OFFSET_S,
        "truth_epoch_gps_ns": EPOCH_GPS_NS,
        "seed": 5,
    }
    clock = ManualClock()
    edges: list[DaqEvent] = []
    other: list[DaqEvent] = []
    done = threading.Event()

    def on_event(ev: DaqEvent) -> None:
        if ev.kind is DaqEventKind.SYNC_EDGE:
            edges.append(ev)
            if len(edges) == len(schedule):
                done.set()
        else:
            other.append(ev)

    session = DaqLink.from_config(
        daq_config(), on_block=lambda b: None, on_event=on_event, clock=clock, backend_options=options
    )
    with session:
        assert done.wait(30.0)
    assert session.error is None
    assert [e.kind for e in other] == [DaqEventKind.STARTED, DaqEventKind.STOPPED]  # no health noise on sync
    reference = SimDaqBackend(**options)  # same sample clock, to ask for true sample times
    return edges, schedule, reference


def test_sync_edges_match_the_true_pulse_times_within_10_us(live_edges) -> None:
    edges, schedule, ref = live_edges
    assert [e.segment for e in edges] == [1] * len(schedule)
    idx = np.array([e.edge_index for e in edges])
    assert all(e.sample_index == int(np.floor(e.edge_index)) for e in edges)
    # the true GPS time of each fractional edge index, from the simulator's own sample clock
    t_edge = np.asarray(ref.sample_time_s(idx, 0.0, RATE))
    t_true = (np.asarray(schedule) - EPOCH_GPS_NS) / 1e9
    err_us = (t_edge - t_true) * 1e6
    rms = np.sqrt(np.mean(err_us**2))
    print(f"sync edge error vs true pulse time: max {np.max(np.abs(err_us)):.2f} µs, rms {rms:.2f} µs")
    assert np.max(np.abs(err_us)) < 10.0


def test_sample_clock_fit_puts_every_sample_on_gps_time(live_edges) -> None:
    edges, schedule, ref = live_edges
    fit = fit_sample_clock([e.edge_index for e in edges], schedule)
    assert fit.n_edges == len(schedule)
    assert fit.ppm(RATE) == pytest.approx(PPM, abs=0.5)
    assert fit.residual_rms_ns < 5_000
    k = np.arange(0, 21_000, 7)
    err_ns = fit.gps_ns(k) - ref.sample_gps_ns(k, 0.0, RATE)
    print(f"GPS time of DAQ samples after the sync fit: max error {np.max(np.abs(err_ns)) / 1e3:.2f} µs")
    assert np.max(np.abs(err_ns)) < 10_000
    # without the sync the nominal clock is off by the offset plus 30 ppm of drift (0.6 ms over 20 s)
    nominal_ns = EPOCH_GPS_NS + np.round(k / RATE * 1e9).astype(np.int64)
    drift_ns = (ref.sample_gps_ns(k, 0.0, RATE) - nominal_ns) - round(OFFSET_S * 1e9)
    assert np.max(np.abs(drift_ns)) > 500_000


def test_shares_the_gnss_simulators_sync_schedule_and_time_base() -> None:
    """The GNSS simulator's SyncSchedule and SimTimeBase drive the DAQ's sync line directly."""
    from sim_devices.gnss.timebase import SimTimeBase, SyncSchedule

    tb = SimTimeBase.from_gps_start(2400, 345600.0)
    assert tb.truth_start_gps_ns == EPOCH_GPS_NS
    schedule = SyncSchedule((EPOCH_GPS_NS + 2_000_000_001, EPOCH_GPS_NS + 4_500_000_000))
    src = SyncPulseOutput.from_gps(schedule, tb)
    assert src.edge_times_s == pytest.approx((2.000000001, 4.5), abs=1e-12)
    assert src.edge_times_s == pytest.approx(schedule.truth_times_s(tb), abs=1e-12)
    assert SyncPulseOutput.from_gps(list(schedule.pulse_gps_ns), EPOCH_GPS_NS) == src
    b = SimDaqBackend(timebase=tb, clock_ppm=PPM)
    assert b.truth_start_ns == tb.truth_start_ns and b.truth_epoch_gps_ns == EPOCH_GPS_NS
    # sample k at true GPS time epoch + k / (rate · (1 + ppm)) for an acquisition started at t = 0
    k = np.array([0, 1000, 3_600_000])
    expected = EPOCH_GPS_NS + np.round(k / (RATE * (1 + PPM * 1e-6)) * 1e9).astype(np.int64)
    np.testing.assert_array_equal(b.sample_gps_ns(k, 0.0, RATE), expected)
