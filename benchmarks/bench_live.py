"""Does the live view slow the recorder? The same simulated recording without and with ``--live`` and N
connected Foxglove WebSocket clients (each subscribed to every live channel).

Prints, per run: messages recorded, dropped, late and stalled channels (the recorder's own verdicts),
CPU seconds of this process (user + system, the recorder, the live feed and the in-process clients)
and wall time; with --live, what the live feed published, decimated and dropped, and the messages
each client received. Goal: the same dropped / late / stalled figures with and without the live view.
Run from the repository root (the simulated devices run in their own process, as in ``rig sim record``)::

    python benchmarks/bench_live.py [--drive step_steer:lead_s=2,hold_s=20] [--speed 1] [--clients 3] [--token]

``--token`` adds a third run with a token: the clients go through the token gate (rig.live.gate).
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def run(drive: str, speed: float, clients: int, live: bool, token: str | None = None) -> dict[str, Any]:
    from drivers.relay.endpoints import Secret
    from rig.live import LIVE_TOPICS, LiveOptions, LiveView
    from rig.live.layout import message_paths, session_layout
    from rig.record.recording import Recording
    from rig.sim.record import record_simulated
    from tests.live.wsclient import collect
    from tests.session.recording import FAST_RTK, config

    cfg = config(drive, speed)
    view = LiveView(LiveOptions(port=0, token=Secret(token) if token else None)) if live else None
    topics = sorted({p.split(".")[0] for p in message_paths(__import__("json").loads(session_layout().to_json()))}
                    | set(LIVE_TOPICS))
    received: list[int] = []
    threads: list[threading.Thread] = []
    done = threading.Event()

    def client() -> None:
        assert view is not None
        url = f"ws://127.0.0.1:{view.ws_port}/" + (f"?token={token}" if token else "")
        got = collect(url, topics, counts=dict.fromkeys(topics, 10 ** 9), timeout_s=600.0, stop=done)
        received.append(sum(len(v) for v in got.messages.values()))

    def started(s: Recording) -> None:
        if view is not None:
            view.attach(s)
            for i in range(clients):
                th = threading.Thread(target=client, name=f"bench-client-{i}")
                th.start()
                threads.append(th)

    with tempfile.TemporaryDirectory() as tmp:
        cpu0, t0 = _cpu_s(), time.monotonic()
        rec = record_simulated(cfg, tmp, name="bench", rtk=FAST_RTK, on_started=started, device_process=True)
        wall, cpu = time.monotonic() - t0, _cpu_s() - cpu0
        done.set()
        for th in threads:
            th.join(30.0)
        stats = view.feed.stats if view is not None and view.feed is not None else None
        if view is not None:
            view.detach()
    s = rec.summary
    return {
        "messages": s.recording.messages, "dropped": s.recording.dropped, "late": len(s.late),
        "stalled": sum(n for n, _ in s.stalled.values()), "cpu_s": cpu, "wall_s": wall,
        "live_published": stats.published if stats else 0, "live_decimated": stats.decimated if stats else 0,
        "live_dropped": stats.dropped if stats else 0, "client_messages": received,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--drive", default="step_steer:lead_s=2,hold_s=20")
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--clients", type=int, default=3)
    ap.add_argument("--token", action="store_true", help="also a run with a token (clients through the gate)")
    a = ap.parse_args()
    token = "bench-token-0123456789"
    for live, tok in [(False, None), (True, None)] + ([(True, token)] if a.token else []):
        r = run(a.drive, a.speed, a.clients, live, tok)
        label = (f"--live, {a.clients} clients" + (", token" if tok else "")) if live else "no live view"
        print(f"{label:>20}: {r['messages']} messages, dropped {r['dropped']}, late {r['late']}, "
              f"stalls {r['stalled']}, CPU {r['cpu_s']:.1f} s in {r['wall_s']:.1f} s wall")
        if live:
            print(f"{'':>20}  live: published {r['live_published']}, decimated {r['live_decimated']}, "
                  f"dropped {r['live_dropped']}; per client received {r['client_messages']}")


if __name__ == "__main__":
    main()
