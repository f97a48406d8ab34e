"""The Foxglove layout of a vsc-rig session (``rig layout``; ``examples/foxglove-layout.json``), built
with the ``foxglove.layouts`` types of foxglove-sdk.

It works on a recorded session file and on the live view (``rig record --live``). Panels: the map of
both antennas, β reference ± band against the VSC estimate, yaw rate, a_y, SWA and speed, RTK status
per rover, LTR with its warning, and the events. The β reference and LTR are not recorded topics
(they are computed afterwards by ``rig validate`` / ``rig rollover``): their panels read the live-only
channels (:data:`rig.live.feed.LIVE_TOPICS`) and stay empty on a file; a note panel says so.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import foxglove.layouts as fl

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from rig.live.feed import LIVE_TOPICS, TOPIC_LIVE_LOG, TOPIC_LIVE_LTR, TOPIC_LIVE_SIDESLIP, TOPIC_LIVE_STATUS

__all__ = ["layout_json", "message_paths", "session_layout"]

_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd")


def _plot(title: str, series: Sequence[tuple[str, str]], *, y_label: str, dashed: Sequence[str] = ()) -> fl.PlotPanel:
    paths = [fl.PlotSeries(value=path, label=label, color=_COLORS[i % len(_COLORS)],
                           line_style="dashed" if path in dashed else "solid")
             for i, (path, label) in enumerate(series)]
    return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=paths, y_axis_label=y_label, show_legend=True,
                                                          following_view_width=30.0))


def session_layout(antenna_a: str = "rover_a", antenna_b: str = "rover_b", bus: str = "vsc") -> fl.Layout:
    """The layout for the receivers of antennas A and B and the CAN bus that carries the VSC roles."""
    fix_a, fix_b = T.gnss_fix(antenna_a), T.gnss_fix(antenna_b)
    roles = T.can_roles(bus)
    live_only = ", ".join(f"`{t}`" for t in LIVE_TOPICS)
    note = (
        "### vsc-rig\n"
        f"Live-only channels (served by `rig record --live`, not in the session file): {live_only}. "
        "On a recorded file the β-reference and LTR panels stay empty: run `rig validate` / `rig rollover`.\n\n"
        "Angles in deg, yaw rate in rad/s, SWA in rad, speeds in m/s (SI as recorded)."
    )
    map_panel = fl.MapPanel(title="Antennas A and B", config=fl.MapConfig(
        follow_topic=fix_a, topic_colors={fix_a: "#1f77b4", fix_b: "#d62728"}, zoom_level=18.0,
        topic_config={fix_a: fl.MapTopicSettings(history_mode="last-n-seconds", time_window_seconds=120.0),
                      fix_b: fl.MapTopicSettings(history_mode="last-n-seconds", time_window_seconds=120.0)},
    ))
    beta = _plot("β reference ± band vs VSC estimate (live)", [
        (f"{TOPIC_LIVE_SIDESLIP}.beta_ref_deg", "β reference"),
        (f"{TOPIC_LIVE_SIDESLIP}.beta_ref_low_deg", "reference − band"),
        (f"{TOPIC_LIVE_SIDESLIP}.beta_ref_high_deg", "reference + band"),
        (f"{TOPIC_LIVE_SIDESLIP}.beta_vsc_deg", "VSC estimate (live)"),
    ], y_label="β (deg)",
        dashed=(f"{TOPIC_LIVE_SIDESLIP}.beta_ref_low_deg", f"{TOPIC_LIVE_SIDESLIP}.beta_ref_high_deg"))
    vsc_rec = _plot("VSC estimate (recorded)", [(f"{roles}.roles.vsc_beta_estimate", "VSC β (rad)")],
                    y_label="β (rad)")
    yaw = _plot("Yaw rate", [(f"{roles}.roles.yaw_rate", "yaw rate (rad/s)")], y_label="rad/s")
    ay = _plot("Lateral acceleration", [(f"{roles}.roles.lat_accel", "a_y (m/s²)")], y_label="m/s²")
    swa = _plot("Steering-wheel angle", [(f"{roles}.roles.swa", "SWA (rad)")], y_label="rad")
    speed = _plot("Speed", [(f"{roles}.roles.vehicle_speed", "CAN vehicle speed"),
                            (f"{T.gnss_bestvel(antenna_a)}.hor_speed_mps", "GNSS A horizontal speed")],
                  y_label="m/s")
    rtk = fl.StateTransitionsPanel(title="RTK status", config=fl.StateTransitionsConfig(paths=[
        fl.StateTransitionsSeries(value=f"{T.gnss_bestpos(antenna_a)}.pos_type", label=f"{antenna_a} (A)"),
        fl.StateTransitionsSeries(value=f"{T.gnss_bestpos(antenna_b)}.pos_type", label=f"{antenna_b} (B)"),
    ]))
    ltr = _plot("LTR (live)", [(f"{TOPIC_LIVE_LTR}.ltr", "LTR"), (f"{TOPIC_LIVE_LTR}.ltr_predicted", "predicted"),
                               (f"{TOPIC_LIVE_LTR}.warning_level", "warning")], y_label="LTR")
    warning = fl.IndicatorPanel(title="Rollover warning (live)", config=fl.IndicatorConfig(
        path=f"{TOPIC_LIVE_LTR}.warning", style="background", font_size=48.0, fallback_color="#2ca02c",
        fallback_label="LTR ok",
        rules=[fl.IndicatorRule(raw_value="true", operator="=", color="#d00000", label="ROLLOVER WARNING")],
    ))
    events = fl.TabContainer(selected_tab_index=0, tabs=[
        fl.TabItem(title="Events (recorded)", content=fl.RawMessagesPanel(
            title="/rig/events", config=fl.RawMessagesConfig(topic_path=f"{T.TOPIC_EVENTS}.text"))),
        fl.TabItem(title="Log (live)", content=fl.LogPanel(title="Events", config=fl.LogConfig(
            topic_to_render=TOPIC_LIVE_LOG, show_name=True, font_size=14.0))),
        fl.TabItem(title="Status (live)", content=fl.RawMessagesPanel(
            title="Status", config=fl.RawMessagesConfig(topic_path=TOPIC_LIVE_STATUS))),
        fl.TabItem(title="Notes", content=fl.MarkdownPanel(title="About this layout", config=fl.MarkdownConfig(
            render_mode="static", markdown=note))),
    ])

    def split(direction: str, *items: tuple[float, Any]) -> fl.SplitContainer:
        return fl.SplitContainer(direction=direction,  # type: ignore[arg-type]
                                 items=[fl.SplitItem(proportion=p, content=c) for p, c in items])

    left = split("column", (3.0, map_panel), (1.0, rtk), (1.5, events))
    middle = split("column", (1.0, beta), (1.0, vsc_rec), (1.0, ltr), (0.5, warning))
    right = split("column", (1.0, yaw), (1.0, ay), (1.0, swa), (1.0, speed))
    return fl.Layout(content=split("row", (1.2, left), (1.0, middle), (1.0, right)))


def layout_json(layout: fl.Layout) -> str:
    """The layout as the Foxglove app imports it (indented, one trailing newline)."""
    import json

    return json.dumps(json.loads(layout.to_json()), indent=2, ensure_ascii=False) + "\n"


_PATH_KEYS = ("value", "path", "topicPath", "followTopic", "topicToRender")


def message_paths(doc: Any) -> Iterator[str]:
    """Every topic or message path a layout document names (plot series, indicators, map topics, …)."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            if k in _PATH_KEYS and isinstance(v, str) and v.startswith("/"):
                yield v
            elif k in ("topicColors", "topicConfig") and isinstance(v, dict):
                yield from (t for t in v if t.startswith("/"))
            else:
                yield from message_paths(v)
    elif isinstance(doc, list):
        for v in doc:
            yield from message_paths(v)
