"""``rig demo``: the whole job on simulated devices, stage by stage.

The demo reads the shipped simulated-car configuration (``rig/examples/sim.toml``), drives the
simulated car through its test programme and writes what an engineer would get from a real test
day into one output folder. Each stage writes its own files and a line of summary, so a failing
stage says which part of the chain broke.

Stages (in order): ``simulate`` (ground truth of the drive, as Parquet/CSV, and an overview plot);
``record`` (the whole simulated session recorded by the real ``rig record`` code path into
``session/``: base and rovers on pseudo-terminals with the correction relay, the VSC ECU on CAN,
the DAQ with the optical sensor and the sync switch; then what the file holds per topic, its size
and its timing quality, scored against the simulator's truth).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from rig.core.config import SessionConfig, load_session
from sim_devices.vehicle import Drive, GroundTruth, VehicleParams, demo_drive, simulate, write_truth
from vsccore.errors import ConfigError

__all__ = ["DemoResult", "StageResult", "demo_config_path", "demo_drive_for", "run_demo"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class StageResult:
    """What one stage of the demo produced."""

    name: str
    summary: str
    files: tuple[Path, ...]
    seconds: float


@dataclass(slots=True)
class DemoResult:
    """All stages of one demo run."""

    out_dir: Path
    stages: list[StageResult] = field(default_factory=list)


def demo_config_path() -> Path:
    """The shipped configuration of the simulated car."""
    return Path(str(resources.files("rig") / "examples" / "sim.toml"))


def demo_drive_for(cfg: SessionConfig, *, fast: bool) -> Drive:
    """The test programme of the demo (see :func:`sim_devices.vehicle.demo_drive`).

    ``fast`` keeps the short CI programme (8 s straights, five steering-ratio circles); without it
    the straights are longer and the circles cover −480° … +480° in 120° steps.
    """
    sim = cfg.simulation
    if sim is None:
        raise ConfigError("the demo needs a [simulation] table in its configuration")
    if fast:
        return demo_drive(heading_deg=sim.initial_heading_deg)
    return demo_drive(heading_deg=sim.initial_heading_deg, straight_s=20.0, swa_step_deg=120.0, gap_s=5.0)


def _stage(result: DemoResult, name: str, fn: Callable[[], tuple[str, tuple[Path, ...]]]) -> None:
    t0 = time.perf_counter()
    summary, files = fn()
    result.stages.append(StageResult(name, summary, files, time.perf_counter() - t0))
    log.info("demo stage %s: %s", name, summary)


def run_demo(out_dir: Path, *, fast: bool = False, config: Path | None = None) -> DemoResult:
    """Run every stage of the demo into ``out_dir`` (created); return what each stage wrote."""
    out_dir.mkdir(parents=True, exist_ok=True)
    cfg = load_session(config or demo_config_path())
    if cfg.vehicle is None:
        raise ConfigError("the demo configuration has no vehicle")
    params = VehicleParams.from_mapping(cfg.vehicle.model_dump(), section="vehicle")
    result = DemoResult(out_dir)
    truth_box: list[GroundTruth] = []

    def simulate_stage() -> tuple[str, tuple[Path, ...]]:
        sim = cfg.simulation
        assert sim is not None  # checked by demo_drive_for
        drive = demo_drive_for(cfg, fast=fast)
        truth = simulate(
            drive,
            params,
            origin=(sim.origin_lat_deg, sim.origin_lon_deg, sim.origin_h_m),
            initial_heading_deg=sim.initial_heading_deg,
            seed=sim.seed,
        )
        truth_box.append(truth)
        csv_path = write_truth(truth, out_dir / "truth.csv")
        png = out_dir / "truth.png"
        _plot_truth(truth, png)
        forward = truth.vx > 0.5  # reversing (steering-ratio circles) has β near 180° by definition
        beta = np.degrees(np.abs(truth.beta_cg[forward]))
        summary = (
            f"{truth.t[-1] - truth.t[0]:.1f} s drive at {1.0 / truth.dt:.0f} Hz, "
            f"max speed {truth.speed.max() * 3.6:.0f} km/h, max |β| driving forward {beta.max():.2f}°, "
            f"max |LTR| {np.abs(truth.ltr).max():.2f}"
        )
        return summary, (csv_path, png)

    _stage(result, "simulate", simulate_stage)

    def record_stage() -> tuple[str, tuple[Path, ...]]:
        return _record(cfg, out_dir / "session", truth_box[0], demo_drive_for(cfg, fast=fast), fast=fast,
                       config=config or demo_config_path())

    _stage(result, "record", record_stage)
    session = out_dir / "session" / "demo"
    _stage(result, "calibrate", lambda: _calibrate(session, out_dir))
    _stage(result, "steering-ratio", lambda: _steering_ratio(session, out_dir))
    _stage(result, "validate", lambda: _validate(session, out_dir / "report"))
    _stage(result, "rollover", lambda: _rollover(session, out_dir))
    return result


DEMO_FAST_SPEED = 8.0
"""Clock speed of ``rig demo --fast``. The simulated receivers and ECU run in their own process
(``device_process``), so the recording process keeps up at this rate on a two-core laptop; with
every device in one process the interpreter lock starves the DAQ reader and the CAN reader from 5×."""


def _record(
    cfg: SessionConfig, out: Path, truth: GroundTruth, drive: Drive, *, fast: bool, config: Path
) -> tuple[str, tuple[Path, ...]]:
    """Record the simulated session; summarise what the file holds and how well its streams are timed."""
    from rig.data import load_session as load_recording
    from rig.sim.record import record_simulated
    from rig.sim.truth import timing_vs_truth

    sim = cfg.simulation
    assert sim is not None
    speed = max(sim.speed, DEMO_FAST_SPEED) if fast else sim.speed
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("demo.*.mcap"):
        old.unlink()
    rec = record_simulated(cfg, out, name="demo", drive=drive, speed=speed, truth=truth, config_path=config,
                           device_process=True)
    summary = rec.summary
    if summary.recording.error is not None:
        raise summary.recording.error
    ds = load_recording(out / "demo")
    size = sum(p.stat().st_size for p in summary.parts)
    health = rec.world.health()
    skipped = sum(v.get("frames_skipped", 0) + v.get("bytes_overrun", 0) + v.get("bytes_dropped", 0)
                  for v in health.values())
    fixed = []
    for rx in ds.receivers():
        g = ds.gnss(rx)
        if len(g.bestpos):
            fixed.append(f"{rx} {100.0 * float(np.mean(g.rtk_fixed)):.0f} %")
    head = (
        f"{rec.world.duration_s:.0f} s drive (+{rec.world.lead_s:.0f} s lead) at {speed:g}× in {rec.wall_s:.1f} s: "
        f"{summary.recording.messages} messages, {size / 1e6:.1f} MB, dropped {summary.recording.dropped}, "
        f"simulated devices behind {skipped}, device errors {sum(summary.device_errors.values())}"
    )
    lines = [head, "    " + rec.governor_text, "    RTK fixed: " + (", ".join(fixed) or "-")]
    for topic, n in sorted(ds.topic_counts.items()):
        lines.append(f"    {topic:<28} {n:>8}")
    if speed > 1.0:
        lines.append(f"    (at {speed:g}× the host's scheduling delays count {speed:g}× in simulated time, so "
                     "host-stamped streams look later than at 1×; `rig sim record --speed 1` shows real-time figures)")
    for t in timing_vs_truth(ds, cfg):
        lines.append(f"    timing {t.stream}: error vs truth mean {t.mean_ns / 1e3:+.1f} µs, "
                     f"max {t.max_abs_ns / 1e3:.1f} µs ({t.n} samples)")
    tb = ds.timebase_records()
    last: dict[str, int] = {}
    for i in range(len(tb)):
        last[str(tb["clock"][i])] = i
    for clock, i in sorted(last.items()):
        if tb["method"][i] == "sync_pulse":
            lines.append(f"    time base {clock}: sync pulse, {int(tb['n'][i])} edges, "
                         f"rms {tb['rms_ns'][i] / 1e3:.1f} µs, drift {tb['drift_ppm'][i]:+.1f} ppm")
        else:
            lines.append(f"    time base {clock}: host envelope, jitter {tb['jitter_ns'][i] / 1e6:.2f} ms, "
                         f"drift {tb['drift_ppm'][i]:+.1f} ppm")
    return "\n".join(lines), summary.parts


def _plot_truth(truth: GroundTruth, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(12, 8), layout="constrained")
    ax = axes[0, 0]
    ax.plot(truth.east, truth.north, lw=0.8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="east [m]", ylabel="north [m]", title="track (CG)")
    ax = axes[0, 1]
    ax.plot(truth.t, truth.speed * 3.6, lw=0.8)
    ax.set(xlabel="t [s]", ylabel="speed [km/h]", title="speed")
    ax = axes[1, 0]
    ax.plot(truth.t, np.degrees(truth.beta_cg), lw=0.8, label="β at CG")
    ax.plot(truth.t, np.degrees(truth.swa) / 100.0, lw=0.8, label="SWA / 100")
    ax.set(xlabel="t [s]", ylabel="[deg]", title="sideslip and steering")
    ax.legend()
    ax = axes[1, 1]
    ax.plot(truth.t, truth.ltr, lw=0.8)
    ax.set(xlabel="t [s]", ylabel="LTR [-]", title="lateral load transfer ratio")
    for a in axes.flat:
        a.grid(True, lw=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _calibrate(session: Path, out_dir: Path) -> tuple[str, tuple[Path, ...]]:
    """Mounting offset and optical zero from the straight runs, recorded next to the session."""
    from rig.data.inputs import load_inputs
    from rig.data.sidefiles import update_calibration_file
    from rig.evaluate.calibrate import (
        baseline_record,
        calibrate_baseline,
        format_baseline,
        optical_record,
        plot_baseline,
    )

    inputs = load_inputs(session, truth=True, optical=True)
    cal = calibrate_baseline(inputs)
    files = [plot_baseline(cal, out_dir / "calibrate-baseline.png")]
    files.append(update_calibration_file(session, "mount_offset", baseline_record(cal)))
    if cal.optical:
        files.append(update_calibration_file(session, "optical_zero", optical_record(cal)))
    text = format_baseline(cal)
    head = f"mounting offset {cal.offset_deg:+.3f}° ± {cal.u95_deg:.3f}° (95 %)"
    if cal.truth_offset_deg is not None:
        head += f", simulator truth {cal.truth_offset_deg:+.3f}° (error {cal.offset_deg - cal.truth_offset_deg:+.3f}°)"
    return head + "\n" + "\n".join("    " + line for line in text.splitlines()), tuple(files)


def _validate(session: Path, report_dir: Path) -> tuple[str, tuple[Path, ...]]:
    """Reference sideslip (calibration from the previous stage applied), VSC estimate scored, HTML report."""
    from rig.evaluate.report import write_validation_report
    from rig.evaluate.validate import validate_session, validation_lines

    sv = validate_session(session)
    files = write_validation_report(sv, report_dir)
    verdict = "PASS" if sv.passed else "FAIL (the simulated VSC estimator is imperfect on purpose)"
    lines = validation_lines(sv)
    return f"VSC sideslip estimate: {verdict}\n" + "\n".join("    " + line for line in lines), (
        files.html,
        files.metrics_json,
        files.metrics_csv,
    )


def _rollover(session: Path, out_dir: Path) -> tuple[str, tuple[Path, ...]]:
    """LTR from lateral acceleration and roll, its 1–3 s prediction and warnings, against the true LTR."""
    from rig.evaluate.report import plot_rollover
    from rig.evaluate.validate import rollover_session

    rep = rollover_session(session)
    png = plot_rollover(rep, out_dir / "rollover.png")
    text = f"LTR ({rep.model} prediction): peak |LTR| {float(np.nanmax(np.abs(rep.ltr))):.2f}"
    if rep.ltr_error_rms is not None and rep.ltr_error_max is not None:
        text += f", error vs the true LTR RMS {rep.ltr_error_rms:.3f} (max {rep.ltr_error_max:.3f})"
    first = rep.prediction.first_warning_s()
    text += "; no rollover warning" if first is None else f"; first warning (prediction ≥ 0.9) at {first:.1f} s"
    return text, (png,)


def _steering_ratio(session: Path, out_dir: Path) -> tuple[str, tuple[Path, ...]]:
    """Steering ratio from the constant-SWA circles of the drive, against the simulator's steering gear."""
    from rig.data.inputs import load_inputs
    from rig.data.sidefiles import update_calibration_file
    from rig.evaluate.calibrate import calibrate_steering_ratio, format_steering, plot_steering, steering_record

    cal = calibrate_steering_ratio(load_inputs(session, truth=True, optical=False))
    files = (plot_steering(cal, out_dir / "steering-ratio.png"),
             update_calibration_file(session, "steering_ratio", steering_record(cal)))
    text = format_steering(cal)
    return text.splitlines()[0] + "\n" + "\n".join("    " + line for line in text.splitlines()[1:]), files
