"""The gate's timing figure is a bound of the map's error, not of the frames' latency (issue 15, H21).

A CAN frame's time on the common base is its interface stamp through the device → host → GPS maps; how
late the host read it does not enter. The figure (:meth:`rig.core.timebase.ClockEstimator.map_error_ns` of
both maps plus :data:`rig.core.quality.FLOOR_ALLOWANCE_MS`) must stay at or above the true error and come
near it; the previous figure (:meth:`~rig.core.timebase.ClockEstimator.envelope_error_ns`: the 95th
percentile, per second, of the lowest pair's height above the map) read every second whose frames were
all late as map error and refused good sessions.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from rig.core.config import load_session as load_config
from rig.core.quality import FLOOR_ALLOWANCE_MS, THRESHOLDS, Figure, StreamQuality, Verdict
from rig.core.timebase import ClockEstimator, causality_bound_ns
from rig.core.topics import EventKind
from rig.data import Session, load_session
from rig.data.verdicts import daq_causality_ns, session_verdicts
from rig.sim.record import record_simulated
from rig.workflows.demo import demo_config_path
from sim_devices.gnss import RtkParams
from sim_devices.vehicle.scenarios import make_scenario
from tests.quality.synth import rewrite
from vsccore.gpstime import gps_ns_to_unix_ns

IntArray = npt.NDArray[np.int64]
MS = 1_000_000
NS = 1_000_000_000
STEP_NS = 3 * MS
STEP_FROM_S, STEP_FOR_S = 6.0, 20.0


def figure(q: StreamQuality, name: str) -> float:
    return judged(q, name).value


def judged(q: StreamQuality, name: str) -> Figure:
    """The figure itself (the stream's verdict also counts its gaps: the governed demo's CAN stream may end
    a second early, which is not what is under test here)."""
    return next(f for f in q.figures if f.name == name)


def _estimator(dev: IntArray, host: IntArray) -> ClockEstimator:
    order = np.argsort(dev, kind="stable")
    est = ClockEstimator("can:test")
    est.add_many(dev[order], host[order])
    return est


def _true_error_ns(ds: Session, true_dev: IntArray) -> npt.NDArray[np.float64]:
    """|time on the common base − true transmit time| of every frame (the simulated host clock is true UTC)."""
    fr = ds.can_frames("vsc")
    assert fr.time_source == "interface"
    return np.abs(fr.time_ns - true_dev).astype(np.float64)


def _old_figure_ms(ds: Session) -> float:
    """The previous statistic, composed as the gate composed it (CAN envelope error + host map envelope error)."""
    fr = ds.can_frames("vsc")
    est = _estimator(fr.records["device_ts_ns"].astype(np.int64), fr.records["host_ts_ns"].astype(np.int64))
    host = ds.host_clock
    assert host is not None
    can_e, host_e = est.envelope_error_ns(), host.envelope_error_ns()
    assert can_e is not None and host_e is not None
    return (can_e + host_e) / MS


# ---------------------------------------------------------------------------------------------
# On the estimator: latency is not map error; a clock step is
# ---------------------------------------------------------------------------------------------

def _pairs(seed: int = 3) -> tuple[IntArray, IntArray]:
    """60 s of a 100 Hz stream: the true event times and a prompt link (exponential latency, mean 0.3 ms)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 60 * NS, 10 * MS, dtype=np.int64)
    return t, t + rng.exponential(0.3 * MS, t.size).astype(np.int64)


def test_seconds_of_late_frames_are_latency_not_map_error() -> None:
    """A reader descheduled for one second in eight, every frame of that second 4 ms late: the map (the floor
    of the other seconds) is right, so the frames' times are; the old per-second p95 called it 4 ms."""
    t, host = _pairs()
    late = ((t // NS) % 8 == 3) * 4 * MS
    est = _estimator(t, host + late)
    true_err = np.abs(est.mapping()(t) - t).max()
    assert true_err < 0.05 * MS
    fig = est.map_error_ns()
    assert fig is not None and true_err <= fig + FLOOR_ALLOWANCE_MS * MS and fig < 0.05 * MS
    old = est.envelope_error_ns()
    assert old is not None and old > 3.9 * MS  # old code: 4 ms, "degraded" on its own


def test_a_device_clock_step_is_map_error_and_rated_at_its_height() -> None:
    """The interface clock set back 3 ms for 20 s of 60 (a resync): the lower envelope rests on the other 40 s,
    so every frame of those 20 s is mapped 3 ms early. The figure is that height, within the floor's scatter."""
    t, host = _pairs()
    dev = t - STEP_NS * ((t >= 20 * NS) & (t < 40 * NS))
    est = _estimator(dev, host)
    true_err = np.abs(est.mapping()(dev) - t).max()
    assert true_err == pytest.approx(STEP_NS, abs=0.05 * MS)
    fig = est.map_error_ns()
    assert fig is not None
    assert true_err <= fig + FLOOR_ALLOWANCE_MS * MS
    assert fig == pytest.approx(STEP_NS, abs=0.05 * MS)


def test_the_bound_holds_on_both_sides_of_the_map() -> None:
    """Module docstring of rig.core.quality: on each window, −h ≤ map − truth ≤ ε (ε: how late the window's most prompt
    pair still was). With a floor that wanders by ±1 ms over tens of seconds, the true error stays inside."""
    t, host = _pairs(5)
    wander = (1 * MS * np.sin(2 * np.pi * t / (40 * NS))).astype(np.int64)
    dev = t - wander  # the clock relation wanders: truth is what the map should follow
    est = _estimator(dev, host)
    err = est.mapping()(dev) - t
    heights = est.floor_heights()
    assert heights is not None
    fig = est.map_error_ns()
    assert fig is not None and fig == heights[1].max()
    assert np.abs(err).max() <= fig + FLOOR_ALLOWANCE_MS * MS
    assert fig <= np.abs(err).max() + 0.1 * MS  # and tight: the wander is what it reports


def test_a_stream_shorter_than_two_windows_is_judged_on_half_its_span() -> None:
    """A starved reader's 2.5 s of frames, each bin's floor higher than the last: not one window with its one
    prompt frame (figure 0), but windows of half the span."""
    t = np.arange(0, int(2.5 * NS), 2 * MS, dtype=np.int64)
    est = _estimator(t, t + t // 2)  # half a second behind per second
    fig = est.map_error_ns()
    assert fig is not None and fig > 0.4 * NS


# ---------------------------------------------------------------------------------------------
# On a governed simulated recording
# ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def governed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The governed clock at 8× (the demo's ``--fast`` clock): the simulated time waits for a starved reader, so
    the frames are on time against the truth whatever the host's load. The receivers' output latency is stated
    (20 ms, as the twins are set), so that these tests judge the map-error figure alone: a latency measured from
    the DAQ is short by the DAQ's most prompt delivery, which the figure's allowance covers only up to 0.2 ms (a
    loaded CI run: true error 0.31 ms against a figure of 0.28 ms; tests/session and tests/dataset score the
    measurement itself)."""
    out = tmp_path_factory.mktemp("governed")
    cfg = load_config(demo_config_path(), {"simulation.speed": 8.0, "simulation.governed": True,
                                           "simulation.gnss.output_latency_s": 0.02,
                                           "receivers.1.output_latency_s": 0.02, "receivers.2.output_latency_s": 0.02})
    rec = record_simulated(cfg, out, name="governed", drive=make_scenario("straight", speed_kmh=50.0, duration_s=30.0),
                           lead_s=6.0, rtk=RtkParams(time_to_float_s=0.5, time_to_fix_s=1.0))
    assert rec.completed and rec.summary.recording.error is None
    return out / "governed"


def _device_stamps(path: Path) -> IntArray:
    return load_session(path).can_frames("vsc").records["device_ts_ns"].astype(np.int64)


def test_a_governed_recording_is_good_and_its_figure_bounds_the_true_error(governed: Path) -> None:
    ds = load_session(governed)
    v = session_verdicts(ds)
    can = v["can:vsc"]
    true_err = _true_error_ns(ds, _device_stamps(governed))
    fig = figure(can, "timing_error_ms")
    print(f"governed 8x: CAN figure {fig:.3f} ms, old figure {_old_figure_ms(ds):.3f} ms, "
          f"true max {true_err.max() / MS:.3f} ms")
    # the governed clock keeps the frames at the host's read floor: 1–180 µs measured, whatever the load
    assert true_err.max() < 0.5 * MS
    assert true_err.max() / MS <= fig < THRESHOLDS["timing_error_ms"].degraded_above
    assert figure(can, "timing_error_ms") >= figure(v["gnss:rover_a"], "host_map_error_ms") >= FLOOR_ALLOWANCE_MS
    assert judged(can, "timing_error_ms").verdict is Verdict.GOOD
    assert judged(v["gnss:rover_a"], "host_map_error_ms").verdict is Verdict.GOOD


def test_a_governed_recording_whose_reader_was_descheduled_is_still_good(governed: Path, tmp_path: Path) -> None:
    """The same recording with every frame of two seconds in ten read 2 ms late (the reader descheduled, as on
    the stressed hosts where the old figure rated governed demo sessions degraded at 1.03–1.34 ms while their
    true CAN error was ≤ 42 µs). The interface stamps are untouched, so the true error is too."""
    true_dev = _device_stamps(governed)

    def hiccups(t: IntArray, host: IntArray, dev: IntArray) -> tuple[IntArray, IntArray, npt.NDArray[np.bool_]]:
        return dev, host + np.isin((t // NS) % 10, (3, 4)) * 2 * MS, np.ones(t.size, dtype=bool)

    ds = load_session(rewrite(governed, tmp_path, "hiccups", hiccups))
    true_err = _true_error_ns(ds, true_dev)
    assert true_err.max() < 0.5 * MS
    can = session_verdicts(ds)["can:vsc"]
    fig = figure(can, "timing_error_ms")
    old = _old_figure_ms(ds)
    print(f"descheduled reader: CAN figure {fig:.3f} ms, old figure {old:.3f} ms, "
          f"true max {true_err.max() / MS:.3f} ms")
    assert judged(can, "timing_error_ms").verdict is Verdict.GOOD, can.message()
    assert true_err.max() / MS <= fig
    # old code: one device-time second in ten or more was late throughout (> 5 %): its p95 read about 2 ms
    # (1.86 ms seen under a stress load: a per-second envelope's floor moves with the host) → "degraded", or
    # "unusable" when the host map's own envelope adds to it (6.74 ms in one idle CI run)
    assert old > 1.5 and THRESHOLDS["timing_error_ms"].judge(old) is not Verdict.GOOD


def test_a_3_ms_interface_clock_step_for_20_s_is_rated_at_3_ms(governed: Path, tmp_path: Path) -> None:
    """Injected map error: the interface clock set back 3 ms for 20 s (the host reads unchanged). Those frames
    are 3 ms early on the common base; the figure is that, plus the host map's bound (its own figure)."""
    true_dev = _device_stamps(governed)
    first = int(true_dev.min())

    def step(_t: IntArray, host: IntArray, dev: IntArray) -> tuple[IntArray, IntArray, npt.NDArray[np.bool_]]:
        rel = dev - first
        inside = (rel >= STEP_FROM_S * NS) & (rel < (STEP_FROM_S + STEP_FOR_S) * NS)
        return dev - STEP_NS * inside, host, np.ones(host.size, dtype=bool)

    ds = load_session(rewrite(governed, tmp_path, "step", step))
    true_err = _true_error_ns(ds, true_dev)
    assert true_err.max() == pytest.approx(STEP_NS, abs=0.5 * MS)  # the step on top of the recording's own
    v = session_verdicts(ds)
    can = v["can:vsc"]
    fig = figure(can, "timing_error_ms")
    host_fig = figure(v["gnss:rover_a"], "host_map_error_ms")
    print(f"3 ms step: CAN figure {fig:.3f} ms (host map {host_fig:.3f} ms), true max {true_err.max() / MS:.3f} ms")
    # stated tolerance: at or above the true error, and above it by no more than the host map's own figure
    # (its bound plus the allowance; the CAN floor's tilt between the two unstepped ends is inside it)
    assert true_err.max() / MS <= fig <= true_err.max() / MS + host_fig
    assert abs(fig - STEP_NS / MS) <= host_fig
    assert judged(can, "timing_error_ms").verdict is Verdict.DEGRADED
    assert can.verdict is not Verdict.GOOD and "timing error" in can.message()


# ---------------------------------------------------------------------------------------------
# Causality: a constant lateness of the host map's own pairs (H31)
# ---------------------------------------------------------------------------------------------

LATE_NS = 3 * MS
"""The receiver's configured output latency is this much shorter than its true one: every GNSS pair is late by
it beyond what the time base takes off, so the host → GPS map puts host instants 3 ms early — the free-running
simulator's receivers writing late, a wrong ``receivers.N.output_latency_s``: no statistic of the pairs sees it."""
ABOVE_TOL_MS = 1.0
"""Stated tolerance of the figure above the true error: it adds the floors' bounds and the 0.2 ms allowance to
the causality bound (0.2–0.61 ms on governed 8× runs, 0.77 ms at a load average of 17 on 2 cores). Below the
truth it falls short by at most the DAQ's own prompt delivery latency (0.1–1 ms of simulated time at 8×,
depending on the host's load), which the test measures against the simulator's truth."""


def _daq_blocks(seed: int = 7) -> tuple[IntArray, IntArray]:
    """60 s of 10 Hz DAQ blocks: each block's last sample time and its host arrival (exponential latency, mean 1 ms)."""
    rng = np.random.default_rng(seed)
    last = np.arange(0, 60 * NS, 100 * MS, dtype=np.int64)
    return last, last + rng.exponential(1 * MS, last.size).astype(np.int64)


def test_causality_bound_is_the_map_early_by_less_the_prompt_delivery() -> None:
    last, arrival = _daq_blocks()
    assert causality_bound_ns(last, arrival) == 0.0  # a right map: every block arrives after its last sample
    b = causality_bound_ns(last, arrival - LATE_NS)  # the map puts every arrival 2 ms early
    assert b is not None and LATE_NS - 0.2 * MS <= b <= LATE_NS  # a lower bound, short by the prompt latency


def test_one_wild_block_does_not_condemn_a_session() -> None:
    """A block stamped 50 ms early (a host clock glitch, a sample index that jumped), then two more far apart:
    each shows in one half-second, not in three within 10 s. Held in three half-seconds of 10 s it counts."""
    last, arrival = _daq_blocks()
    wild = arrival.copy()
    wild[[100, 300, 500]] -= 50 * MS
    assert causality_bound_ns(last, wild) == 0.0
    wild[[105, 110]] -= 50 * MS  # 0.5 s and 1 s after the first: three bins of one window
    b = causality_bound_ns(last, wild)
    assert b is not None and b > 40 * MS  # 50 ms less the wild blocks' own delivery latency
    assert causality_bound_ns(last[:8], arrival[:8]) is None  # two bins: not judged


def _live_verdicts(ds: Session) -> dict[str, dict[str, Any]]:
    """The verdicts the recorder wrote at the end of the recording (its ``timebase`` event)."""
    evs = [e for _t, e in ds.events if e.kind is EventKind.TIMEBASE and "verdicts" in e.details]
    assert len(evs) == 1
    return dict(evs[0].details["verdicts"])


def _live_figure(v: dict[str, dict[str, Any]], stream: str, name: str) -> tuple[float, str]:
    f = v[stream]["figures"][name]
    return float(f["value"]), str(f["verdict"])


@pytest.fixture(scope="module")
def late_receiver(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The governed 8× recording with the reference receiver's output latency configured 2 ms short of the
    simulator's: a known constant offset of the host map, whatever the host's load."""
    out = tmp_path_factory.mktemp("late_receiver")
    cfg = load_config(demo_config_path())
    i = next(k for k, r in enumerate(cfg.receivers) if r.name == "rover_a")
    assert cfg.simulation is not None
    stated = 0.02 - LATE_NS / NS  # the simulated receivers' latency set to 20 ms, configured 2 ms short
    cfg = load_config(demo_config_path(), {"simulation.speed": 8.0, "simulation.governed": True,
                                           "simulation.gnss.output_latency_s": 0.02,
                                           f"receivers.{i}.output_latency_s": stated})
    rec = record_simulated(cfg, out, name="late", drive=make_scenario("straight", speed_kmh=50.0, duration_s=20.0),
                           lead_s=6.0, rtk=RtkParams(time_to_float_s=0.5, time_to_fix_s=1.0))
    assert rec.completed and rec.summary.recording.error is None
    return out / "late"


def _daq_prompt_delivery_ns(ds: Session) -> float:
    """The DAQ's prompt delivery latency the causality bound falls short by, against the simulator's truth: the
    true time of each block's last sample (the ``sim`` event's sample clock) to its host arrival (the simulated
    host clock is true UTC), taken as :func:`causality_bound_ns` takes it (a known 50 ms shift off the result)."""
    dev = ds.daq_devices()[0]
    sim = [e for _t, e in ds.events if e.source == "sim" and "sample0_gps_ns" in e.details]
    assert len(sim) == 1 and ds.leap_seconds is not None
    g0 = gps_ns_to_unix_ns(int(sim[0].details["sample0_gps_ns"]), ds.leap_seconds)
    _first, last, host = ds.daq_blocks(dev)
    true_last = (g0 + last.astype(np.float64) * (1e9 / float(sim[0].details["true_rate_hz"]))).astype(np.int64)
    shifted = causality_bound_ns(true_last + 50 * MS, host)
    assert shifted is not None
    return 50 * MS - shifted


def test_a_constant_host_map_offset_is_not_rated_good(late_receiver: Path) -> None:
    """Old code: host map figure 0.2–0.8 ms, CAN figure the same, both good, while every CAN frame is 2 ms early
    (measured with a 2 ms offset). Now the DAQ's causality shows the offset: the CAN figure is degraded and within
    the stated tolerance of the true error, offline and in the recorder's own verdicts alike."""
    ds = load_session(late_receiver)
    true_err = _true_error_ns(ds, _device_stamps(late_receiver))
    true_ms = float(true_err.max()) / MS
    assert true_ms == pytest.approx(LATE_NS / MS, abs=0.5)  # the offset, plus the governed recording's own
    b, why = daq_causality_ns(ds, ds.daq_devices()[0])
    assert b is not None, why
    delivery_ms = _daq_prompt_delivery_ns(ds) / MS
    v = session_verdicts(ds)
    can = judged(v["can:vsc"], "timing_error_ms")
    host = figure(v["gnss:rover_a"], "host_map_error_ms")
    live = _live_verdicts(ds)
    live_can, live_verdict = _live_figure(live, "can:vsc", "timing_error_ms")
    live_host, _ = _live_figure(live, "gnss:rover_a", "host_map_error_ms")
    print(f"{LATE_NS / MS:g} ms late receiver: causality {b / MS:.3f} ms (DAQ prompt delivery {delivery_ms:.3f} ms), "
          f"host map figure {host:.3f} ms (live {live_host:.3f}), CAN figure {can.value:.3f} ms (live {live_can:.3f}), "
          f"true max {true_ms:.3f} ms")
    # a lower bound of the error, short of it by the DAQ's prompt delivery (and the host map's own scatter)
    assert true_ms - delivery_ms - 0.15 <= b / MS <= true_ms
    # The live figure comes from the recorder's per-bin prompt DAQ blocks (ClockEstimator.floor_pairs), a coarser
    # sample of the same causality than the offline one's every block: a CI run on 4 workers under load measured
    # it 0.41 ms below the offline figure (2.749 vs 3.161 ms, true 3.003 ms, DAQ delivery 0.083 ms).
    below_tol_ms = {"offline": 0.15, "live": 0.6}
    for kind, fig, verdict in (("offline", can.value, can.verdict.value), ("live", live_can, live_verdict)):
        assert true_ms - delivery_ms - below_tol_ms[kind] <= fig <= true_ms + ABOVE_TOL_MS, kind
        assert verdict == Verdict.DEGRADED.value
    assert host >= b / MS + FLOOR_ALLOWANCE_MS and live_host >= b / MS - 0.5


def test_a_governed_recording_shows_no_causality_violation(governed: Path) -> None:
    """The governed clock keeps the receivers on time: the DAQ's causality shows at most what the allowance already
    covers (the governed host map's own 0.1 ms, measured against the truth), and the recorder's verdicts stay good."""
    ds = load_session(governed)
    b, why = daq_causality_ns(ds, ds.daq_devices()[0])
    assert b is not None and b < FLOOR_ALLOWANCE_MS * MS, why
    live = _live_verdicts(ds)
    for stream, name in (("can:vsc", "timing_error_ms"), ("gnss:rover_a", "host_map_error_ms")):
        value, verdict = _live_figure(live, stream, name)
        assert verdict == Verdict.GOOD.value, (stream, value)
