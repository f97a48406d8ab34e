"""``rig campaign``: validate every session of a test campaign as Dask tasks (:mod:`rig.workflows.campaign`).

    rig campaign sessions/ --out campaign/ [--workers 4] [--estimator a.mod:fn --estimator b.mod:fn]
    rig campaign 'sessions/2026-*/**' --scheduler tcp://10.0.0.5:8786 --out campaign/ --calibrate --rollover

Exit status: 0 when the campaign ran (a failing session is a row of the table with its error), 2 on an error that
stops it (no sessions, bad option, unwritable --out, unreachable scheduler).
"""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer


class MethodChoice(StrEnum):
    """``--method``: the reference methods of ``rig validate``."""

    RAW = "raw"
    WAVELET = "wavelet"
    RTS = "rts"


class KeyChoice(StrEnum):
    """``--cache-key``: the values of :class:`rig.workflows.campaign.KeyMode`."""

    QUICK = "quick"
    FULL = "full"


def campaign(
    sessions: Annotated[list[str], typer.Argument(help="Directories (searched recursively), session parts or glob "
                                                   "patterns (quote them) naming the sessions.")],
    out: Annotated[Path, typer.Option("--out", help="Output directory: metrics.parquet, compare.parquet, "
                                      "report.html, campaign.json and the cache.")],
    scheduler: Annotated[
        str | None,
        typer.Option("--scheduler", help="Dask scheduler address (tcp://host:8786; its workers need vsc-rig and the "
                     "session paths), or 'serial' to run in this process. Default: a local cluster."),
    ] = None,
    workers: Annotated[int, typer.Option("--workers", help="Worker processes of the local cluster (0: serial).")] = 2,
    estimator: Annotated[
        list[str] | None,
        typer.Option("--estimator", help="Score package.module:function (as rig validate --estimator); repeat to "
                     "compare estimators side by side; 'vsc_beta_estimate' is the recorded estimate (the default)."),
    ] = None,
    calibrate: Annotated[bool, typer.Option("--calibrate", help="Estimate each session's antenna mounting offset "
                                            "(calibrate-baseline) and validate with it.")] = False,
    rollover: Annotated[bool, typer.Option("--rollover", help="Add each session's LTR summary (rig rollover).")]
    = False,
    method: Annotated[
        MethodChoice, typer.Option("--method", help="Reference sideslip noise treatment.", case_sensitive=False)
    ] = MethodChoice.RTS,
    cache_key: Annotated[
        KeyChoice,
        typer.Option("--cache-key", help="quick: each part's size, mtime and MCAP footer/summary hash; full: every "
                     "byte.", case_sensitive=False),
    ] = KeyChoice.QUICK,
    no_report: Annotated[bool, typer.Option("--no-report", help="No report.html.")] = False,
) -> None:
    """Validate every session of a campaign as Dask tasks: one Parquet metrics table and an HTML trend report.

    Sessions already analysed (same content, estimator and options) come from the cache under --out; a failing
    session is a row with its error and never stops the campaign.
    """
    from rig.workflows.campaign import RECORDED_ESTIMATE, CampaignOptions, KeyMode, find_sessions, run_campaign

    found = find_sessions(sessions)
    ests = tuple(None if e == RECORDED_ESTIMATE else e for e in estimator) if estimator else (None,)
    opts = CampaignOptions(estimators=ests, method=method.value,
                           calibrate=calibrate, rollover=rollover, key_mode=KeyMode(cache_key.value))
    res = run_campaign(found, out, opts, scheduler=scheduler, workers=workers, report=not no_report,
                       progress=lambda m: typer.echo(m, err=True))
    typer.echo(f"{res.sessions} sessions on {res.scheduler}: {res.computed} validations computed, {res.cached} from "
               f"the cache, {res.failed} failed, {res.rows} rows in {res.elapsed_s:.1f} s")
    for path, est, err in res.errors:
        typer.echo(f"failed: {path} [{est}]: {err}")
    typer.echo(f"wrote {res.table}" + (f", {res.compare}" if res.compare else "")
               + (f", {res.report}" if res.report else "") + f", {res.manifest}")
