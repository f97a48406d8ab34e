"""Sessions written by the recorder from synthetic data of known truth, read back through rig.data."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

import rig.core.topics as T  # noqa: N812 - short alias
from rig.data import align, load_session
from rig.store import scan_part
from tests.dataset.synth import (
    BESTPOSB_BYTES,
    DAQ_G0,
    OUTPUT_LATENCY_S,
    TRUE_RATE,
    Synth,
    sync_pulses,
    tx_ns,
    utc,
    write_session,
)
from vsccore.errors import SessionFileError


@pytest.fixture(scope="module")
def synth(tmp_path_factory: pytest.TempPathFactory) -> Synth:
    return write_session(tmp_path_factory.mktemp("ds"))


def test_all_parts_read_in_order(synth: Synth) -> None:
    s = load_session(synth.base)
    assert len(s.parts) >= 3 and not s.warnings
    total = sum(scan_part(p, collect=False).message_count for p in s.parts)
    assert sum(s.topic_counts.values()) == total
    assert s.config["output"]["name"] == "synth"
    assert s.vehicle["wheelbase_m"] == 2.87 and s.calibration["mount_offset_deg"] == 0.1
    assert "vsc_sim.dbc" in s.attachments
    marks = [e for _t, e in s.events if e.kind is T.EventKind.MARK]
    assert len(marks) == 1 and marks[0].text.startswith("operator mark")
    assert len(s.part_ends) == len(s.parts)


def test_gnss_tables_exact(synth: Synth) -> None:
    s = load_session(synth.base)
    assert s.receivers() == ["rover_a", "rover_b"] and s.leap_seconds == 18
    for r in ("rover_a", "rover_b"):
        g = s.gnss(r)
        truth = synth.gnss[r]
        assert np.array_equal(g.bestpos["gps_time_ns"], truth["gps"])
        assert np.array_equal(g.bestpos.time_ns, utc(truth["gps"]))
        assert np.array_equal(g.bestpos["lat_deg"], truth["lat"])
        assert np.array_equal(g.bestpos.valid, truth["valid"])
        assert np.all(np.isnan(g.bestpos["diff_age_s"]))  # null → NaN
        assert np.array_equal(g.rtk_fixed, truth["valid"])
        assert len(g.bestvel) == truth["gps"].size and len(g.heading) == 0
    assert len(s.gnss("rover_a").marktime) == synth.pulses_gps.size


def test_can_roles_through_vectorised_decoder(synth: Synth) -> None:
    s = load_session(synth.base)
    frames = s.can_frames("can0")
    assert len(frames) == synth.can_t_gps.size and frames.time_source == "interface"
    err = frames.time_ns - utc(synth.can_t_gps)
    assert np.max(np.abs(err)) < 1_000_000  # interface clock → host → GPS within 1 ms
    # the receivers' constant 20 ms output latency and the 2.26 ms a BESTPOSB takes on the wire at
    # 460800 Bd are invisible to the envelope; they come from the recorded configuration
    unaware = load_session(synth.base, gnss_min_latency_s=0.0).can_frames("can0")
    hidden = OUTPUT_LATENCY_S * 1e9 + tx_ns(BESTPOSB_BYTES)
    assert np.median(unaware.time_ns - utc(synth.can_t_gps)) == pytest.approx(-hidden, abs=1e6)
    roles = s.can_roles("can0")
    yaw = roles["yaw_rate"]
    assert bool(np.all(yaw.ok)) and len(yaw) == synth.can_t_gps.size
    assert np.max(np.abs(yaw.values - synth.yaw_rate)) <= np.deg2rad(0.01) / 2 + 1e-12  # DBC resolution
    ay = roles["lat_accel"]
    assert np.max(np.abs(ay.values - synth.lat_accel)) <= 9.80665 * 1e-4 / 2 + 1e-9
    assert np.array_equal(yaw.timestamps_ns, frames.time_ns)


def test_daq_sync_and_optical(synth: Synth) -> None:
    s = load_session(synth.base)
    d = s.daq("daq1", sync_channel="sync", receiver="rover_a")
    assert d.time_source == "sync_pulse" and len(d) == synth.daq_n and d.lost == 0
    truth = utc(DAQ_G0 + np.round(d.sample_index / TRUE_RATE * 1e9).astype(np.int64))
    err = d.time_ns - truth
    print(f"DAQ via sync pulse: max |error| {np.max(np.abs(err)) / 1e3:.2f} µs")
    assert np.max(np.abs(err)) < 100_000
    assert d.sync is not None and d.sync.drift_ppm == pytest.approx(50.0, abs=2.0)
    plain = s.daq("daq1")
    assert plain.time_source == "log_time" and np.max(np.abs(plain.time_ns - truth)) < 2_000_000
    t, opt = s.optical("s350", synth.spec, sync_channel="sync", receiver="rover_a")
    assert np.array_equal(t, d.time_ns)
    assert np.max(np.abs(opt.vx - synth.vx)) < 1e-4 and np.max(np.abs(opt.vy - synth.vy)) < 1e-4
    assert bool(np.all(opt.valid))
    # resampled onto the GNSS times
    g = s.gnss("rover_a").bestpos
    vx_at_gnss = align(g.time_ns, t, opt.vx)
    inside = np.isfinite(vx_at_gnss)
    assert inside.sum() > 0.9 * len(g)


def test_truth_round_trip(synth: Synth) -> None:
    tr = load_session(synth.base).truth()
    assert np.array_equal(tr.truth.t, synth.truth.t)
    for name in ("east", "yaw_rate", "ltr"):
        assert np.array_equal(getattr(tr.truth, name), getattr(synth.truth, name))
    assert np.array_equal(tr.truth.wheel_load, synth.truth.wheel_load)
    assert tr.truth.lat0_deg == 48.7
    assert np.array_equal(tr.time_ns, synth.truth_t0_utc + np.round(synth.truth.t * 1e9).astype(np.int64))


def test_missing_corrupt_and_truncated_parts(synth: Synth, tmp_path: Path) -> None:
    parts = load_session(synth.base).parts
    for p in parts:
        shutil.copy(p, tmp_path / p.name)
    base = tmp_path / synth.base.name
    # truncated last part (crashed recorder): read with a warning
    last = tmp_path / parts[-1].name
    data = last.read_bytes()
    last.write_bytes(data[: len(data) * 2 // 3])
    s = load_session(base)
    assert s.warnings and parts[-1].name in s.warnings[0]
    with pytest.raises(SessionFileError, match=parts[-1].name):
        load_session(base, allow_truncated=False)
    # a damaged middle part: the error names the file and the part
    mid = tmp_path / parts[1].name
    scan = scan_part(mid)
    raw = bytearray(mid.read_bytes())
    c = scan.chunks[len(scan.chunks) // 2]
    raw[c.offset + c.length - 30] ^= 0x55
    before = load_session(base, topics=[T.TOPIC_EVENTS]).topic_counts
    mid.write_bytes(bytes(raw))
    # a damaged chunk in a middle part: skipped with a warning naming the part, the chunk, its span and
    # topics; every other chunk is read (was: the whole session refused with "CRC mismatch")
    s = load_session(base, topics=[T.TOPIC_EVENTS])
    ((where, region),) = s.damage
    assert where == mid and region.chunks == (len(scan.chunks) // 2,) and region.offset == c.offset
    lost = region.messages
    assert lost is not None and lost > 0 and region.topics
    assert sum(s.topic_counts.values()) == sum(before.values()) - lost
    damaged = [w for w in s.warnings if "damaged chunk" in w]
    assert len(damaged) == 1 and f"{parts[1].name} (part 2 of {len(parts)})" in damaged[0]
    (ev,) = s.damage_events()
    assert ev.severity is T.Severity.WARNING and ev.details["topics"] == list(region.topics)
    assert (ev.start_ns, ev.end_ns) == (region.start_ns, region.end_ns)
    # a missing part
    mid.unlink()
    with pytest.raises(SessionFileError, match=rf"{parts[1].name}: part 1 of session synth is missing"):
        load_session(base)


def test_receiver_output_latency_from_the_receiver_config(tmp_path: Path) -> None:
    """A real receiver's fixed output latency is configured per receiver (``receivers[].output_latency_s``)."""
    synth = write_session(tmp_path, "real", duration_s=8.0, rollover_bytes=None, simulated=False)
    s = load_session(synth.base)
    assert "simulation" not in s.config
    assert s.gnss_output_latency_ns("rover_a") == round(OUTPUT_LATENCY_S * 1e9)
    g = s.gnss("rover_a").bestpos["gps_time_ns"][:3]
    expected = round(OUTPUT_LATENCY_S * 1e9) + tx_ns(BESTPOSB_BYTES)
    assert np.array_equal(s.gnss_log_latency_ns("rover_a", "BESTPOS", g), np.full(3, expected))
    err = s.can_frames("can0").time_ns - utc(synth.can_t_gps)
    assert np.max(np.abs(err)) < 1_000_000 and not s.warnings


@pytest.fixture(scope="module")
def reconnect(tmp_path_factory: pytest.TempPathFactory) -> Synth:
    """A DAQ that lost its USB link twice: three acquisitions, the last one short and between two sync pulses."""
    duration = 20.0
    rel = (sync_pulses(duration) - DAQ_G0) / 1e9
    quiet = float(rel[rel > 15.3][0]) + 0.3  # after a pulse's falling edge, ≥ 0.9 s before the next rising one
    segments = [(0.0, 8.0), (9.3, 15.0), (quiet, quiet + 0.6)]
    return write_session(tmp_path_factory.mktemp("reconnect"), "reconnect", duration_s=duration, rollover_bytes=None,
                         daq_segments=segments)


def test_daq_segments_after_a_reconnect_are_fitted_separately(reconnect: Synth) -> None:
    s = load_session(reconnect.base)
    d = s.daq("daq1", sync_channel="sync", receiver="rover_a")
    assert len(d) == reconnect.daq_n and [seg.n_samples for seg in d.segments] == [8000, 5700, 600]
    err = d.time_ns - utc(reconnect.daq_true_gps)
    # the two acquisitions that saw sync pulses: each on GPS time within 0.1 ms
    assert [seg.time_source for seg in d.segments] == ["sync_pulse", "sync_pulse", "host"]
    assert d.time_source == "sync_pulse+host"
    synced = d.synced
    assert synced.sum() == 13_700 and np.max(np.abs(err[synced])) < 100_000
    for seg in d.segments[:2]:
        assert seg.sync is not None and seg.sync.matched_edges.size >= 2
        assert seg.sync.drift_ppm == pytest.approx(50.0, abs=5.0)
    # the short one without an edge: the host clock, flagged and warned about
    assert np.max(np.abs(err[~synced])) < 1_000_000
    assert d.segments[2].sync is None and "not synchronised" in d.segments[2].note
    assert any("segment 3 of 3" in w for w in s.warnings)
