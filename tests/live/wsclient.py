"""A minimal Foxglove WebSocket protocol client on the ``websockets`` package: advertise → subscribe →
binary message data, as the Foxglove app does it.

The protocol is ``foxglove.websocket.v1``; foxglove-sdk 0.30's server accepts it under its new name
``foxglove.sdk.v1`` only (same messages), and the client offers both."""

from __future__ import annotations

import asyncio
import json
import re
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from websockets.asyncio.client import connect
from websockets.typing import Subprotocol

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
OP_MESSAGE_DATA = 0x01
_MSG_HEADER = struct.Struct("<BIQ")  # opcode, subscription id, log time (ns)


@dataclass
class Received:
    advertised: dict[str, dict[str, Any]] = field(default_factory=dict)
    """topic → channel advertisement (id, encoding, schemaName, schema, schemaEncoding)."""
    messages: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    """topic → (log time ns, payload) in arrival order."""
    server_info: dict[str, Any] = field(default_factory=dict)
    subprotocol: str = ""
    statuses: list[dict[str, Any]] = field(default_factory=list)
    """The server's status messages (e.g. its refusal of a subscription: "Unknown channel ID: 2")."""


async def _collect(url: str, topics: list[str], counts: dict[str, int], timeout_s: float,
                   stop: threading.Event | None, until: Callable[[Received], bool] | None = None,
                   headers: dict[str, str] | None = None) -> Received:
    out = Received()
    subs: dict[int, str] = {}
    subscribed: dict[int, int] = {}  # channel id -> subscription id
    retries = 0
    deadline = time.monotonic() + timeout_s
    async with connect(url, subprotocols=[Subprotocol(p) for p in SUBPROTOCOLS], max_size=None,
                       additional_headers=headers) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        out.subprotocol = str(ws.subprotocol)
        while True:
            if all(len(out.messages.get(t, ())) >= counts.get(t, 1) for t in topics) and (
                until is None or until(out)
            ):
                return out
            left = deadline - time.monotonic()
            if left <= 0 or (stop is not None and stop.is_set()):
                return out
            try:
                frame = await asyncio.wait_for(ws.recv(), min(left, 0.2) if stop is not None else left)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "serverInfo":
                    out.server_info = msg
                elif msg["op"] == "status":
                    out.statuses.append(msg)
                    # foxglove-sdk 0.30 can refuse a subscription to a channel it has just advertised ("Unknown
                    # channel ID: N"; seen once in CI, 2026-12-03, through the token gate): it advertises before
                    # the channel takes subscriptions. Ask again for a channel still advertised, a few times.
                    refused = re.search(r"[Uu]nknown channel(?: ID)?:? *(\d+)", str(msg.get("message", "")))
                    if refused and retries < 20:
                        cid = int(refused.group(1))
                        sid = subscribed.get(cid)
                        if sid is not None and any(ch["id"] == cid for ch in out.advertised.values()):
                            retries += 1
                            await asyncio.sleep(0.05)
                            await ws.send(json.dumps({"op": "subscribe",
                                                      "subscriptions": [{"id": sid, "channelId": cid}]}))
                elif msg["op"] == "advertise":
                    new = []
                    for ch in msg["channels"]:
                        out.advertised[ch["topic"]] = ch
                        if ch["topic"] in topics and ch["id"] not in subscribed:
                            sid = len(subs) + 1
                            subs[sid] = ch["topic"]
                            subscribed[ch["id"]] = sid
                            new.append({"id": sid, "channelId": ch["id"]})
                    if new:
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
            else:
                op, sid, log_ns = _MSG_HEADER.unpack_from(frame)
                if op == OP_MESSAGE_DATA and sid in subs:
                    out.messages.setdefault(subs[sid], []).append((log_ns, bytes(frame[_MSG_HEADER.size:])))


def collect(url: str, topics: list[str], counts: dict[str, int] | None = None, timeout_s: float = 30.0,
            stop: threading.Event | None = None, until: Callable[[Received], bool] | None = None,
            headers: dict[str, str] | None = None) -> Received:
    """Connect (with extra request ``headers``), subscribe to ``topics`` as they are advertised, and read
    until each has ``counts[topic]`` messages (default 1) and ``until`` (if given) holds, ``timeout_s``
    passed or ``stop`` is set."""
    return asyncio.run(_collect(url, topics, counts or {}, timeout_s, stop, until, headers))
