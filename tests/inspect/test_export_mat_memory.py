"""``rig export --format mat``'s sideslip struct with bounded memory (issue 17).

The struct comes from ``load_inputs(bounded_memory=True)`` (only the topics the series need; each CAN bus read
a batch of blocks at a time, keeping the whole bus's frames only as their clock readings) and from the
reference and estimate alone (no manoeuvres, scores or steering reconstruction). Tolerance: none. The streamed
CAN roles, the GNSS series and the sideslip struct equal the whole-session computation (``load_inputs`` and
``rig.evaluate.validate.validate_session``) bit for bit, with batches and slices forced far smaller than the session.
The peak memory itself is measured by ``benchmarks/bench_export.py --formats mat+sideslip``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import rig.data.inputs as sd
from rig.data import Session, load_session
from rig.export.mat import export_mat
from tests.dataset.synth import Synth
from tests.dataset.synth import write_session as write_dataset_session
from tests.inspect.recorded import record_validating_drive

SIDESLIP_FIELDS = ("time_ns", "time_s", "reference_rad", "reference_sigma_rad", "estimate_rad", "error_rad")


@dataclass(frozen=True)
class Drive:
    base: Path


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Drive:
    """A simulated drive that validates (dual-antenna RTK, the VSC's CAN bus with an interface clock)."""
    return Drive(record_validating_drive(tmp_path_factory.mktemp("mat_memory")))


@pytest.fixture(scope="module")
def ds(tmp_path_factory: pytest.TempPathFactory) -> Synth:
    """Two receivers, a CAN bus whose interface clock drifts against the host, DAQ, truth; several parts."""
    return write_dataset_session(tmp_path_factory.mktemp("ds"), duration_s=6.0)


@pytest.fixture
def small_batches(monkeypatch: pytest.MonkeyPatch) -> None:
    """Batches of 40 frames and slices of 50: a short session streams as a long one does."""
    monkeypatch.setattr(sd, "_CAN_BATCH_ROWS", 40)
    monkeypatch.setattr(sd, "_SLICE", 50)


def _mat_field(ds: Any) -> np.ndarray:
    return np.asarray(ds[()]).reshape(-1)


def _same_inputs(a: sd.SessionInputs, b: sd.SessionInputs) -> None:
    assert a.t0_ns == b.t0_ns
    assert a.load_warnings == b.load_warnings and dict(a.missing) == dict(b.missing)
    assert {k: v.to_dict() for k, v in a.streams.items()} == {k: v.to_dict() for k, v in b.streams.items()}
    assert list(a.can) == list(b.can)
    for role, s in a.can.items():
        r = b.can[role]
        assert (s.unit, s.source) == (r.unit, r.source), role
        for x, y in ((s.time_ns, r.time_ns), (s.t_s, r.t_s), (s.values, r.values), (s.valid, r.valid)):
            assert np.array_equal(x, y, equal_nan=True), role
    assert (a.gnss is None) == (b.gnss is None)
    if a.gnss is not None and b.gnss is not None:
        for f in ("time_ns", "baseline_azimuth_rad", "baseline_length_m", "valid"):
            assert np.array_equal(getattr(a.gnss, f), getattr(b.gnss, f), equal_nan=True), f
        assert np.array_equal(a.gnss.a.velocity_east_mps, b.gnss.a.velocity_east_mps, equal_nan=True)


def test_bounded_load_inputs_equals_the_whole_session(drive: Drive, small_batches: None) -> None:
    """Every CAN role (times, values, validity), the GNSS series, t0, streams and warnings are those of the
    default path, with the bus read 40 frames at a time; the bounded session holds no CAN frames, optical or raw
    topics (the DAQ blocks it keeps: their sync pulse measures the receivers' output latency)."""
    whole = sd.load_inputs(drive.base, optical=False, truth=False)
    bounded = sd.load_inputs(drive.base, optical=False, truth=False, bounded_memory=True)
    assert len(bounded.can) > 3
    _same_inputs(bounded, whole)
    held = set(bounded.session._topics)
    assert not any(t.startswith(("/can/", "/optical/")) or t.endswith(("/raw", "/fix")) for t in held)
    assert any(t.endswith("/bestpos") for t in held)
    # only some roles: the same subset either way, and only their messages decoded
    roles = ("yaw_rate", "vsc_beta_estimate")
    some = sd.load_inputs(drive.base, optical=False, truth=False, bounded_memory=True, can_roles=roles)
    assert tuple(some.can) == roles
    _same_inputs(some, sd.load_inputs(drive.base, optical=False, truth=False, can_roles=roles))


@pytest.mark.parametrize("how", ["fed as read", "in device-time order", "out of order: read again"])
def test_streamed_can_equals_session_can_frames(ds: Synth, small_batches: None, how: str,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """On a session of several parts with a drifting interface clock: the streamed roles (and the first frame
    time) equal Session.can_roles / Session.can_frames, whether the interface clock's envelope is fed as the
    blocks come, from every frame's clock readings in device-time order (``first_time``), or from a second pass
    when the first found the interface times out of order."""
    full: Session = load_session(ds.base)
    lean = load_session(ds.base, include=sd._bounded_topics(optical=False, truth=False))
    passes: list[bool] = []
    read_bus = sd._read_bus

    def spy(*a: Any, **k: Any) -> sd._BusPass:
        bp = read_bus(*a, **k)
        passes.append(k["keep_clocks"])
        if how.startswith("out of order") and len(passes) == 1:
            assert bp.clock is not None  # in order in the file: as if it were not
            bp.clock, bp.monotone = None, False
        return bp

    monkeypatch.setattr(sd, "_read_bus", spy)
    got = sd._streamed_can_roles(lean, "can0", decode=True, first_time=how == "in device-time order")
    assert passes == {"fed as read": [False], "in device-time order": [True],
                      "out of order: read again": [False, True]}[how]
    frames = full.can_frames("can0")
    assert got.error is None and got.time_source == frames.time_source == "interface"
    want = full.can_roles("can0")
    assert list(got.roles) == list(want) and sum(len(s) > 0 for s in want.values()) >= 2
    for role, s in want.items():
        g = got.roles[role]
        assert np.array_equal(g.timestamps_ns, s.timestamps_ns), role
        assert np.array_equal(g.values, s.values, equal_nan=True), role
        assert np.array_equal(g.flags, s.flags), role
    if how == "in device-time order":
        assert got.first_time_ns == int(np.min(frames.time_ns))
        # without GNSS to start the time base, t0 is the first CAN frame's time either way
        assert sd._first_time(lean, {"can0": got}, truth_read=False) == sd._first_time(full)


def test_export_sideslip_equals_validate_session(drive: Drive, tmp_path: Path, small_batches: None,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """The MAT file's sideslip struct equals rig validate's reference, estimate and error exactly; the export
    never gathers the whole CAN bus (Session.can_frames) nor runs the steering reconstruction (1.5 GB of working
    memory on a one-hour session)."""
    import h5py

    import rig.evaluate.validate
    from rig.evaluate.validate import validate_session

    sv = validate_session(drive.base)
    whole_can_frames = Session.can_frames

    def refuse(*_a: Any, **_k: Any) -> Any:
        raise AssertionError("the sideslip struct needs no whole-session CAN frames nor steering reconstruction")

    monkeypatch.setattr(Session, "can_frames", refuse)
    monkeypatch.setattr(rig.evaluate.validate, "reconstruct_steering", refuse)
    report = export_mat(drive.base, tmp_path, topics=["gnss_*"])
    monkeypatch.setattr(Session, "can_frames", whole_can_frames)
    assert "sideslip" in report.files[0].source, report.warnings
    with h5py.File(report.files[0].path, "r") as h:
        got = {k: _mat_field(h["sideslip"][k]) for k in SIDESLIP_FIELDS}
    t0 = sd.load_inputs(drive.base, optical=False, truth=False).t0_ns
    assert got["time_ns"].tolist() == (t0 + np.round(sv.t_s * 1e9).astype(np.int64)).tolist()
    for name, want in (("reference_rad", sv.reference.beta), ("reference_sigma_rad", sv.reference.sigma),
                       ("estimate_rad", sv.estimate_rad), ("error_rad", sv.error_rad)):
        assert np.array_equal(got[name], np.asarray(want, dtype=np.float64), equal_nan=True), name
    assert np.isfinite(got["error_rad"]).sum() > 100
