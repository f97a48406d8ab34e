"""Plots and the HTML report of ``rig validate``, ``rig rollover`` and ``rig steering``.

Matplotlib figures are built with :class:`matplotlib.figure.Figure` (no pyplot state, no display
needed) and saved as PNG. :func:`write_validation_report` writes a self-contained folder: the HTML
page with every plot embedded (base64 PNG, so the page can be mailed on its own), the same PNGs
next to it, ``metrics.json`` and ``metrics.csv``.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vsccore.errors import SessionFileError

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from rig.analysis.scoring import ValidationResult
    from rig.analysis.steering import ErrorModel
    from rig.evaluate.validate import RolloverReport, SessionValidation

__all__ = [
    "ReportFiles",
    "plot_error_model",
    "plot_rollover",
    "write_metrics_csv",
    "write_validation_report",
]


def _figure(rows: int, cols: int, size: tuple[float, float]) -> tuple[Figure, Any]:
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False)
    return fig, axes


def _save(fig: Figure, path: Path) -> Path:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=100)
    except OSError as exc:
        raise SessionFileError(f"cannot write plot {path}: {exc}") from exc
    return path


def _png_bytes(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return buf.getvalue()


def _grid(ax: Axes) -> None:
    ax.grid(True, lw=0.3)


# --------------------------------------------------------------------------------------------
# Steering error model
# --------------------------------------------------------------------------------------------


def plot_error_model(em: ErrorModel, path: Path, *, title: str = "") -> Path:
    """γ(v) in per cent over speed (km/h), with the sign change marked."""
    fig, axes = _figure(1, 1, (7.0, 4.2))
    ax = axes[0, 0]
    ax.plot(em.speeds_mps * 3.6, 100.0 * em.gamma, lw=1.2)
    ax.axhline(0.0, color="k", lw=0.6)
    v0 = em.sign_change_speed_mps
    if v0 is not None:
        ax.axvline(3.6 * v0, color="tab:red", lw=0.8, ls="--", label=f"sign change {3.6 * v0:.1f} km/h")
        ax.legend()
    ax.set(xlabel="speed [km/h]", ylabel="γ = 1 − δ_kin/δ [%]",
           title=title or "relative error of the kinematic road-wheel angle a_y·l/v²")
    _grid(ax)
    return _save(fig, path)


# --------------------------------------------------------------------------------------------
# Rollover
# --------------------------------------------------------------------------------------------


def plot_rollover(rep: RolloverReport, path: Path) -> Path:
    """LTR (estimate, truth when known), its 1/2/3 s predictions shifted to their target times, warnings."""
    fig, axes = _figure(2, 1, (11.0, 7.0))
    ax = axes[0, 0]
    ax.plot(rep.t_s, rep.ltr, lw=1.0, color="k", label="LTR from a_y and roll")
    if rep.truth_t_s is not None and rep.truth_ltr is not None:
        ax.plot(rep.truth_t_s, rep.truth_ltr, lw=0.8, color="tab:green", ls="--", label="true LTR (wheel loads)")
    pred = rep.prediction
    for j, h in enumerate(pred.horizons_s):
        ax.plot(pred.t + h, pred.predicted[:, j], lw=0.7, label=f"predicted {h:g} s ahead (at target time)")
    for lim in (pred.threshold, -pred.threshold):
        ax.axhline(lim, color="tab:red", lw=0.6, ls=":")
    for a, b in pred.warning_intervals:
        ax.axvspan(a, b, color="tab:red", alpha=0.15, lw=0)
    ax.set(xlabel="t [s]", ylabel="LTR [-]", title="lateral load-transfer ratio and its prediction")
    ax.legend(fontsize=7, loc="upper right")
    _grid(ax)
    ax = axes[1, 0]
    ax.step(pred.t, pred.order, where="post", lw=0.8)
    ax.set(xlabel="t [s]", ylabel="model order", title=f"model order in use ({rep.model})")
    _grid(ax)
    return _save(fig, path)


# --------------------------------------------------------------------------------------------
# Validation report
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ReportFiles:
    """What :func:`write_validation_report` wrote."""

    html: Path
    metrics_json: Path
    metrics_csv: Path
    plots: tuple[Path, ...]


def _deg(x: np.ndarray) -> np.ndarray:
    return np.degrees(np.asarray(x, dtype=float))


def _plot_track(sv: SessionValidation) -> Figure:
    fig, axes = _figure(1, 1, (7.0, 6.0))
    ax = axes[0, 0]
    e, n = sv.track_east_m, sv.track_north_m
    ax.plot(e, n, lw=0.6, color="0.6", label="antenna A")
    v = sv.reference.valid
    ax.scatter(e[v], n[v], s=1.5, c="tab:blue", label="reference valid")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="east [m]", ylabel="north [m]", title="track (antenna A)")
    ax.legend(fontsize=8, markerscale=4)
    _grid(ax)
    return fig


def _shade_manoeuvres(ax: Axes, sv: SessionValidation) -> None:
    colours = {"straight": "0.92", "low_speed": "0.85"}
    for m in sv.result.manoeuvres:
        c = colours.get(m.kind.value)
        if c is None:
            continue
        ax.axvspan(m.t_start_s, m.t_stop_s, color=c, lw=0, zorder=0)


def _plot_beta(sv: SessionValidation) -> Figure:
    fig, axes = _figure(1, 1, (12.0, 4.8))
    ax = axes[0, 0]
    t = sv.t_s
    ref = sv.reference
    _shade_manoeuvres(ax, sv)
    b = _deg(ref.beta)
    u = _deg(ref.u95)
    ax.fill_between(t, b - u, b + u, color="tab:blue", alpha=0.25, lw=0, label="GNSS 95 % band")
    ax.plot(t, b, lw=0.9, color="tab:blue", label=f"GNSS reference ({ref.method})")
    if sv.optical is not None:
        ax.plot(t, _deg(sv.optical.beta), lw=0.7, color="tab:orange", label=f"optical ({sv.optical.sensor})")
    ax.plot(t, _deg(sv.estimate_rad), lw=0.8, color="tab:red", label=f"estimate ({sv.result.estimate_source})")
    if sv.truth_beta_rad is not None:
        # only where the references are defined: at walking speed or reversing β is large and meaningless
        # for the validation (it would set the scale of the whole plot)
        shown = np.where(np.isfinite(ref.beta), _deg(sv.truth_beta_rad), np.nan)
        ax.plot(t, shown, lw=0.7, color="k", ls="--", label="simulator truth")
    ax.set(xlabel="t [s]", ylabel="β at CG [deg]",
           title="sideslip: references and estimate (grey: straight / low speed)")
    ax.legend(fontsize=8, loc="upper right")
    _grid(ax)
    return fig


def _plot_error(sv: SessionValidation) -> Figure:
    fig, axes = _figure(2, 1, (12.0, 7.0))
    err = _deg(sv.error_rad)
    ax = axes[0, 0]
    _shade_manoeuvres(ax, sv)
    ax.plot(sv.t_s, err, lw=0.7, color="tab:red", label="estimate − reference")
    u = _deg(sv.reference.u95)
    ax.plot(sv.t_s, u, lw=0.5, color="tab:blue", label="± reference 95 %")
    ax.plot(sv.t_s, -u, lw=0.5, color="tab:blue")
    tol = sv.tolerances.max_abs_rad
    if tol is not None:
        for s in (1.0, -1.0):
            ax.axhline(s * math.degrees(tol), color="k", lw=0.6, ls=":")
    ax.set(xlabel="t [s]", ylabel="error [deg]", title="estimate error over time (dotted: max-abs tolerance)")
    ax.legend(fontsize=8, loc="upper right")
    _grid(ax)
    ax = axes[1, 0]
    ok = np.isfinite(err) & np.isfinite(sv.ay_mps2)
    ax.scatter(sv.ay_mps2[ok], err[ok], s=1.5, alpha=0.5, color="tab:red")
    overall = sv.result.overall.metrics
    if overall is not None:
        for b in overall.bins:
            if b.n == 0:
                continue
            hi = b.hi_mps2 if math.isfinite(b.hi_mps2) else b.lo_mps2 + 2.0
            rms = math.degrees(b.rmse_rad)
            for sgn in (1.0, -1.0):
                ax.hlines(rms, sgn * b.lo_mps2, sgn * hi, color="k", lw=1.2)
                ax.hlines(-rms, sgn * b.lo_mps2, sgn * hi, color="k", lw=1.2)
    ax.set(xlabel="lateral acceleration [m/s²]", ylabel="error [deg]",
           title="error against lateral acceleration (black: ± RMS per |a_y| bin)")
    _grid(ax)
    return fig


def _plot_truth_scores(sv: SessionValidation) -> Figure | None:
    if sv.truth_beta_rad is None:
        return None
    fig, axes = _figure(1, 1, (12.0, 4.0))
    ax = axes[0, 0]
    tru = sv.truth_beta_rad
    ax.plot(sv.t_s, _deg(sv.reference.beta - tru), lw=0.7, label="GNSS reference − truth")
    ax.plot(sv.t_s, _deg(sv.reference.u95), lw=0.5, color="0.5", label="± stated 95 %")
    ax.plot(sv.t_s, -_deg(sv.reference.u95), lw=0.5, color="0.5")
    if sv.optical is not None:
        ax.plot(sv.t_s, _deg(sv.optical.beta - tru), lw=0.7, label="optical − truth")
    ax.set(xlabel="t [s]", ylabel="[deg]", title="references against the simulator's truth")
    ax.legend(fontsize=8, loc="upper right")
    _grid(ax)
    return fig


def _fmt(x: object, nd: int = 3) -> str:
    if x is None:
        return "–"
    if isinstance(x, bool):
        return "PASS" if x else "FAIL"
    if isinstance(x, float):
        return "–" if math.isnan(x) else f"{x:.{nd}f}"
    return html.escape(str(x))


def _table(rows: Sequence[Mapping[str, object]], columns: Sequence[tuple[str, str]]) -> str:
    head = "".join(f"<th>{html.escape(label)}</th>" for _k, label in columns)
    body = []
    for r in rows:
        cells = []
        for k, _label in columns:
            v = r.get(k)
            cls = ""
            if k == "passed" and isinstance(v, bool):
                cls = ' class="pass"' if v else ' class="fail"'
            cells.append(f"<td{cls}>{_fmt(v)}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


_CSS = """
body { font-family: sans-serif; margin: 2em; max-width: 1250px; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.6em; text-align: right; }
th { background: #eee; } td:first-child { text-align: left; }
.pass { background: #d8f5d0; } .fail { background: #f8d0d0; }
.verdict { font-size: 1.4em; padding: 0.3em 0.8em; display: inline-block; }
img { max-width: 100%; } .warn { color: #a60; }
.timing { background: #ffe7a8; border: 2px solid #c80; font-weight: bold; padding: 0.4em 0.8em; }
"""

_MANOEUVRE_COLUMNS = (
    ("kind", "manoeuvre"), ("t_start_s", "start [s]"), ("t_stop_s", "stop [s]"), ("source", "source"),
    ("n", "n"), ("rmse_deg", "RMSE [°]"), ("bias_deg", "bias [°]"), ("max_abs_deg", "max |e| [°]"),
    ("p95_deg", "P95 |e| [°]"), ("lag_s", "lag [s]"), ("valid_fraction", "ref. valid"), ("passed", "verdict"),
)


def _metrics_row(name: str, m: Any) -> dict[str, object]:
    if m is None:
        return {"kind": name, "n": 0}
    return {
        "kind": name,
        "n": m.n_compared,
        "rmse_deg": math.degrees(m.rmse_rad),
        "bias_deg": math.degrees(m.bias_rad),
        "max_abs_deg": math.degrees(m.max_abs_rad),
        "p95_deg": math.degrees(m.p95_abs_rad),
        "lag_s": None if math.isnan(m.lag_s) else m.lag_s,
        "valid_fraction": m.valid_fraction,
        "passed": m.passed,
    }


def write_metrics_csv(rows: Sequence[Mapping[str, object]], path: Path) -> Path:
    """One row per manoeuvre (the per-manoeuvre table), columns as in ``ValidationResult.table_rows``."""
    if not rows:
        cols: list[str] = ["kind"]
    else:
        cols = list(rows[0])
        for r in rows[1:]:
            cols.extend(k for k in r if k not in cols)
    try:
        with path.open("w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=cols)
            w.writeheader()
            for r in rows:
                w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in cols})
    except OSError as exc:
        raise SessionFileError(f"cannot write {path}: {exc}") from exc
    return path


def write_validation_report(sv: SessionValidation, out_dir: Path) -> ReportFiles:
    """Write ``report.html`` (plots embedded), the PNGs, ``metrics.json`` and ``metrics.csv`` into ``out_dir``.

    Raises:
        SessionFileError: the folder or a file cannot be written.
    """
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SessionFileError(f"cannot create report folder {out_dir}: {exc}") from exc
    figures: list[tuple[str, str, Figure]] = [
        ("track.png", "Track map", _plot_track(sv)),
        ("beta.png", "Sideslip references and estimate", _plot_beta(sv)),
        ("error.png", "Estimate error over time and against lateral acceleration", _plot_error(sv)),
    ]
    tf = _plot_truth_scores(sv)
    if tf is not None:
        figures.append(("truth.png", "References against the simulator's truth", tf))
    plots: list[Path] = []
    embedded: list[tuple[str, str]] = []
    for name, caption, fig in figures:
        data = _png_bytes(fig)
        p = out_dir / name
        try:
            p.write_bytes(data)
        except OSError as exc:
            raise SessionFileError(f"cannot write plot {p}: {exc}") from exc
        plots.append(p)
        embedded.append((caption, base64.b64encode(data).decode("ascii")))
    doc = sv.to_dict()
    mj = out_dir / "metrics.json"
    try:
        mj.write_text(json.dumps(doc, indent=1, allow_nan=False), encoding="utf-8")
    except OSError as exc:
        raise SessionFileError(f"cannot write {mj}: {exc}") from exc
    mc = write_metrics_csv(sv.result.table_rows(), out_dir / "metrics.csv")
    page = out_dir / "report.html"
    try:
        page.write_text(_html(sv, embedded), encoding="utf-8")
    except OSError as exc:
        raise SessionFileError(f"cannot write {page}: {exc}") from exc
    return ReportFiles(page, mj, mc, tuple(plots))


def _needed_validity(res: ValidationResult) -> float:
    """Valid fraction of the reference over the manoeuvres that need it (the overall score's span)."""
    m = res.overall.metrics
    return res.reference_valid_fraction if m is None else m.valid_fraction


def _html(sv: SessionValidation, embedded: Sequence[tuple[str, str]]) -> str:
    res = sv.result
    verdict = "PASS" if res.passed else "FAIL"
    cls = "pass" if res.passed else "fail"
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>rig validate — {html.escape(sv.session_name)}</title><style>{_CSS}</style></head><body>",
        f"<h1>VSC sideslip validation — {html.escape(sv.session_name)}</h1>",
        f"<p class='verdict {cls}'>{verdict}</p>",
        *(f"<p class='timing'>{html.escape(w)}</p>" for w in sv.timing_warnings),
        "<ul>",
        f"<li>session: <code>{html.escape(str(sv.session_path))}</code></li>",
        f"<li>estimate: {html.escape(res.estimate_source)}</li>",
        (f"<li>reference: dual-antenna GNSS, method <b>{html.escape(res.reference_method)}</b>, "
         f"valid {100 * _needed_validity(res):.1f} % of the epochs of the manoeuvres that need it "
         f"({100 * res.reference_valid_fraction:.1f} % of the whole drive, low-speed manoeuvring included; "
         f"{html.escape(sv.invalid_summary)})</li>"),
        *([f"<li>{html.escape(sv.reference.source_summary())}</li>"] if sv.reference.source is not None else []),
        f"<li>tolerances: {html.escape(sv.tolerance_text)}</li>",
        f"<li>duration {sv.t_s[-1] - sv.t_s[0]:.1f} s, {sv.t_s.size} GNSS epochs</li>",
        "</ul>",
    ]
    overall = res.overall.metrics
    if overall is not None and overall.failures:
        # two different verdicts: the estimate is wrong, or the reference could not judge it often enough
        est_f = [f for f in overall.failures if not f.startswith("reference valid")]
        ref_f = [f for f in overall.failures if f.startswith("reference valid")]
        if est_f:
            parts.append("<p class='fail'>the estimate failed: " + html.escape("; ".join(est_f)) + "</p>")
        if ref_f:
            parts.append("<p class='fail'>the reference was not valid often enough to judge the estimate: "
                         + html.escape("; ".join(ref_f)) + "</p>")
    for w in sv.warnings:
        if w not in sv.timing_warnings:
            parts.append(f"<p class='warn'>warning: {html.escape(w)}</p>")
    if sv.time_base:
        parts.append("<h2>Time base of the streams used</h2>")
        qrows: list[dict[str, object]] = [{"kind": name, "n": q.verdict.value,
                  "note": "; ".join([f.text() for f in q.figures] + [g.text() for g in q.gaps] + ([q.note] if q.note
                                                                                                 else []))}
                 for name, q in sv.time_base.items()]
        parts.append(_table(qrows, (("kind", "stream"), ("n", "verdict"), ("note", "figures (thresholds), gaps"))))
    parts.append("<h2>Overall and per manoeuvre kind</h2>")
    rows = [_metrics_row("overall (without low speed)", overall)]
    rows.extend(_metrics_row(s.kind.value if s.kind else "?", s.metrics) for s in res.per_kind)
    parts.append(_table(rows, _MANOEUVRE_COLUMNS[:1] + _MANOEUVRE_COLUMNS[4:]))
    if overall is not None and overall.bins:
        parts.append("<h2>Error against |a_y| (overall)</h2>")
        brows = [
            {
                "kind": f"≥ {b.lo_mps2:g} m/s²" if math.isinf(b.hi_mps2) else f"{b.lo_mps2:g}–{b.hi_mps2:g} m/s²",
                "n": b.n,
                "rmse_deg": None if math.isnan(b.rmse_rad) else math.degrees(b.rmse_rad),
                "bias_deg": None if math.isnan(b.bias_rad) else math.degrees(b.bias_rad),
                "max_abs_deg": None if math.isnan(b.max_abs_rad) else math.degrees(b.max_abs_rad),
            }
            for b in overall.bins
        ]
        parts.append(_table(brows, (("kind", "|a_y|"), ("n", "n"), ("rmse_deg", "RMSE [°]"),
                                    ("bias_deg", "bias [°]"), ("max_abs_deg", "max |e| [°]"))))
    parts.append("<h2>Per manoeuvre</h2>")
    parts.append(_table(res.table_rows(), _MANOEUVRE_COLUMNS[:10] + _MANOEUVRE_COLUMNS[11:]))
    if sv.cross_check is not None:
        cc = sv.cross_check
        flag = "DISAGREE" if sv.cross_check_flagged else "agree"
        parts.append(f"<h2>GNSS vs optical cross-check: {flag}</h2>")
        parts.append(
            f"<p>{cc.n_compared} common epochs; mean difference {math.degrees(cc.mean_diff_rad):.3f}°, "
            f"RMS {math.degrees(cc.rms_diff_rad):.3f}°, max {math.degrees(cc.max_abs_diff_rad):.3f}°; "
            f"{100 * cc.fraction_disagree:.1f} % of epochs beyond k = {cc.coverage_factor:g} combined "
            f"uncertainty; {len(cc.segments)} disagreement stretches ≥ 0.5 s.</p>"
        )
    if res.truth:
        parts.append("<h2>References against the simulator's truth</h2>")
        trows = []
        for s in res.truth:
            m = s.metrics
            trows.append({
                "kind": s.name, "n": m.n_compared, "rmse_deg": math.degrees(m.rmse_rad),
                "bias_deg": math.degrees(m.bias_rad), "max_abs_deg": math.degrees(m.max_abs_rad),
                "p95_deg": math.degrees(m.p95_abs_rad), "coverage": s.coverage,
            })
        parts.append(_table(trows, (("kind", "reference"), ("n", "n"), ("rmse_deg", "RMSE [°]"),
                                    ("bias_deg", "bias [°]"), ("max_abs_deg", "max |e| [°]"),
                                    ("p95_deg", "P95 |e| [°]"), ("coverage", "within k·σ"))))
    for caption, b64 in embedded:
        parts.append(f"<h2>{html.escape(caption)}</h2><img alt='{html.escape(caption)}' "
                     f"src='data:image/png;base64,{b64}'>")
    parts.append("</body></html>")
    return "\n".join(parts)
