"""The RTK correction relay of a recording: NTRIP, serial or a receiver's stream to the rovers' correction ports."""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Mapping

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.relay import CorrectionFrame, PushSource, Relay, Sink, open_sink, open_source
from drivers.relay import Source as RelaySource
from drivers.relay.endpoints import RedactedEndpoint, Secret
from rig.core.config import ReceiverConfig, RelayConfig
from rig.core.topics import EventKind, Severity
from rig.record.device import Device, DeviceContext
from rig.record.gnss import GnssDevice
from rig.record.status import DeviceState
from vsccore.errors import ConfigError

__all__ = ["RelayDevice"]

log = logging.getLogger(__name__)


def _receiver(receivers: Mapping[str, GnssDevice], name: str, key: str) -> GnssDevice:
    dev = receivers.get(name)
    if dev is None:
        raise ConfigError(f"{key}: receiver:{name} names no configured receiver ({sorted(receivers)})")
    return dev


class RelayDevice(Device):
    """The RTK correction relay."""

    def __init__(self, ctx: DeviceContext, cfg: RelayConfig, receivers: Mapping[str, GnssDevice],
                 correction_port: Callable[[ReceiverConfig], str | None],
                 gga: Callable[[], tuple[float, float, float] | None]) -> None:
        super().__init__(ctx, "relay", "relay", maxsize=20_000)
        self.cfg = cfg
        self.from_receiver = cfg.source.startswith("receiver:")
        source: RelaySource
        if self.from_receiver:
            rx = _receiver(receivers, cfg.source.removeprefix("receiver:"), "relay.source")
            push = PushSource(cfg.source)
            rx.push = push
            source = push
        else:
            password = None if cfg.source_password is None else Secret(cfg.source_password.get_secret_value())
            source = open_source(
                RedactedEndpoint(cfg.source, password),
                env=os.environ, user_env=cfg.ntrip_user_env, password_env=cfg.ntrip_password_env,
                gga=gga, gga_period_s=cfg.gga_period_s, clock=ctx.clock,
            )
        sinks: list[Sink] = []
        for text in cfg.sinks:
            if text.startswith("receiver:"):
                rx = _receiver(receivers, text.removeprefix("receiver:"), "relay.sinks")
                path = correction_port(rx.rc)
                if path is None:  # the configuration check refuses this: raw RTCM3 into a NOVATEL-mode port
                    raise ConfigError(f"relay.sinks: {text}: no correction_device cabled to its "
                                      f"{rx.rc.correction_port}")
                url = path if ("://" in path or "@" in path) else f"{path}@{rx.rc.correction_baud}"
                sinks.append(open_sink(url, queue_frames=cfg.queue_frames))
            else:
                sinks.append(open_sink(text, queue_frames=cfg.queue_frames))
        self.relay = Relay(
            source, sinks,
            tap=None if self.from_receiver else self._on_tap,
            on_frame=self._on_frame if self.from_receiver else None,
            clock=ctx.clock,
        )
        self._reported_failure = False

    def _on_tap(self, host_ns: int, data: bytes) -> None:
        self.source.put(T.TOPIC_RELAY_RAW, self.ctx.timebase.live_host_to_utc(T.TOPIC_RELAY_RAW, host_ns), host_ns,
                        data)
        self.ctx.board.message(self.name, host_ns)

    def _on_frame(self, host_ns: int, frame: CorrectionFrame) -> None:
        self.source.put(T.TOPIC_RELAY_RAW, self.ctx.timebase.live_host_to_utc(T.TOPIC_RELAY_RAW, host_ns), host_ns,
                        frame.raw)
        self.ctx.board.message(self.name, host_ns)

    def start(self) -> None:
        self.relay.start()
        self.event(EventKind.CONNECT, f"relay {self.cfg.source} → {', '.join(self.cfg.sinks)} started")

    def stop(self) -> None:
        self.relay.stop(drain_s=0.0)

    def publish_stats(self) -> None:
        st = self.relay.stats()
        now = self.ctx.clock.now_ns()
        self.source.put(T.TOPIC_RELAY_STATS, self.ctx.timebase.host_to_utc(now), now, st.to_topic_dict())
        age = "-" if st.last_correction_age_s is None else f"{st.last_correction_age_s:.1f} s"
        self.ctx.board.update(
            self.name,
            detail=f"{st.state} {st.bytes_per_s / 1000:.2f} kB/s age {age} bad {st.rejected_frames} "
            f"drop {st.dropped_frames}",
        )
        if self.relay.error is not None and not self._reported_failure:
            self._reported_failure = True
            self.ctx.board.update(self.name, state=DeviceState.LOST, detail=f"FAILED: {self.relay.error}")
            self.event(EventKind.ERROR, f"relay stopped: {self.relay.error}", severity=Severity.ERROR)

