"""A token gate in front of the Foxglove SDK's WebSocket server: the live view's WebSocket checks the token.

foxglove-sdk (0.30) has no hook to accept or refuse a connection (its ``ServerListener`` hears only
subscriptions, client channels, parameters and services, after the handshake), so with a token the SDK
server listens on ``127.0.0.1`` on an ephemeral port and :class:`TokenGate` listens on the address the
user bound. The gate checks the token at the opening handshake, before any byte of the live data leaves:

- the token comes as the query parameter ``?token=…`` (what a Foxglove app user can type: the app opens a
  URL) or as an ``Authorization: Bearer …`` header (scripts); it is compared in constant time;
- no token or a wrong one: HTTP 401 at the upgrade, no WebSocket;
- the right one: the gate opens the upstream connection with the client's own offer of subprotocols
  (``foxglove.sdk.v1`` / ``foxglove.websocket.v1``), answers the client with the one the SDK chose (or
  the SDK's refusal, status for status), then relays every message both ways, text as text and binary as
  binary, and closes each side with the other's close code.

A slow client holds back its own relay only: the SDK's per-client queue then drops that client's oldest
data messages, as it does for a slow client connected directly; the recorder never waits. The token is a
:class:`~drivers.relay.endpoints.Secret` and is never logged: the request path (which carries it) is
neither logged nor forwarded upstream.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import logging
import socket
import threading
from collections.abc import Sequence
from http import HTTPStatus
from urllib.parse import parse_qsl, urlencode, urlsplit

from websockets.asyncio.client import ClientConnection, connect
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.http11 import Request, Response
from websockets.typing import Subprotocol

from drivers.relay.endpoints import Secret
from vsccore.errors import ConfigError

__all__ = ["TokenGate", "token_of_request"]

log = logging.getLogger(__name__)

# websockets logs the request line (path and query, so the token) at DEBUG: its own logger stops at INFO
_ws_log = logging.getLogger(__name__ + ".websockets")
_ws_log.setLevel(logging.INFO)

UPSTREAM_HOST = "127.0.0.1"


def token_of_request(path: str, headers: Headers) -> str:
    """The token a request carries: ``?token=`` in its path, else ``Authorization: Bearer``; "" without."""
    for key, value in parse_qsl(urlsplit(path).query, keep_blank_values=True):
        if key == "token":
            return value
    auth = headers.get("Authorization", "")
    scheme, _, value = auth.partition(" ")
    return value.strip() if scheme.lower() == "bearer" else ""


def _without_token(path: str) -> str:
    """``path`` with its ``token`` query parameter removed (what goes upstream)."""
    parts = urlsplit(path)
    query = [(k, v) for k, v in parse_qsl(parts.query, keep_blank_values=True) if k != "token"]
    return (parts.path or "/") + (f"?{urlencode(query)}" if query else "")


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    try:
        return socket.create_server((host, port), family=family)
    except OSError as exc:
        raise ConfigError(f"--live {port} --live-bind {host}: cannot serve the live WebSocket: {exc}") from exc


class TokenGate:
    """Serve ``host:port`` (0: any free port) as a token-checking relay to ``ws://127.0.0.1:upstream_port``.

    The listening socket is bound here (a bind failure raises at once); one thread of its own runs the
    asyncio loop until :meth:`stop`.

    Raises:
        ConfigError: the address or port cannot be bound; an empty token.
    """

    def __init__(self, *, host: str, port: int, upstream_port: int, token: Secret) -> None:
        if not token:
            raise ConfigError("live WebSocket gate: an empty token")
        self._token = token.reveal().encode()
        self._upstream_port = upstream_port
        self._sock = _bind(host, port)
        self._port = int(self._sock.getsockname()[1])
        self._upstreams: dict[ServerConnection, ClientConnection] = {}
        # loop and stop event exist before the thread runs: stop() works whenever it comes
        self._loop = asyncio.new_event_loop()
        self._stop = asyncio.Event()
        self._ready = threading.Event()
        self._error: list[BaseException] = []
        self._thread = threading.Thread(target=self._run, name="rig-live-gate")
        self._thread.start()
        self._ready.wait()  # set once serving, or when the loop ended (an error: reported below)
        if self._error:
            self._thread.join(5.0)
            self._sock.close()
            raise ConfigError(f"--live {port} --live-bind {host}: cannot serve the live WebSocket: "
                              f"{self._error[0]}") from self._error[0]

    @property
    def port(self) -> int:
        """The port clients connect to (the one bound, also after :meth:`stop`)."""
        return self._port

    def authorized(self, path: str, headers: Headers) -> bool:
        """Whether the request carries the token (constant-time compare)."""
        return hmac.compare_digest(token_of_request(path, headers).encode(), self._token)

    # the loop's side ------------------------------------------------------------------------------------

    def _run(self) -> None:
        loop = self._loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._main())
        except BaseException as exc:  # reported to the constructor (before ready) or logged
            if not self._ready.is_set():
                self._error.append(exc)
            else:
                log.exception("live WebSocket gate failed")
        finally:
            self._ready.set()
            try:
                loop.run_until_complete(loop.shutdown_asyncgens())
            finally:
                asyncio.set_event_loop(None)
                loop.close()

    async def _main(self) -> None:
        async with serve(self._relay, sock=self._sock, process_request=self._check, process_response=self._done,
                         select_subprotocol=self._subprotocol, compression=None, logger=_ws_log,
                         server_header=None) as server:
            self._ready.set()
            await self._stop.wait()
            await self._close(server)

    async def _close(self, server: Server) -> None:
        server.close(close_connections=True)
        await server.wait_closed()
        for up in list(self._upstreams.values()):
            await up.close()
        self._upstreams.clear()

    async def _check(self, conn: ServerConnection, request: Request) -> Response | None:
        """The token, then the upstream connection with the client's subprotocols; a response refuses."""
        peer = conn.remote_address
        if not self.authorized(request.path, request.headers):
            log.warning("live WebSocket: refused %s: no valid token", peer)
            resp = conn.respond(HTTPStatus.UNAUTHORIZED, "token required: ws://HOST:PORT/?token=...\n")
            resp.headers["WWW-Authenticate"] = 'Bearer realm="vsc-rig live"'
            return resp
        offered = [Subprotocol(p.strip()) for v in request.headers.get_all("Sec-WebSocket-Protocol")
                   for p in v.split(",") if p.strip()]
        url = f"ws://{UPSTREAM_HOST}:{self._upstream_port}{_without_token(request.path)}"
        try:
            up = await connect(url, subprotocols=offered or None, compression=None, max_size=None,
                               ping_interval=None, open_timeout=10.0)
        except InvalidStatus as exc:  # the SDK's own refusal (e.g. no subprotocol it speaks), passed on
            status = exc.response.status_code
            log.info("live WebSocket: the Foxglove server refused %s (%d)", peer, status)
            return conn.respond(status, exc.response.body.decode(errors="replace") or f"{status}\n")
        except (OSError, TimeoutError) as exc:
            log.error("live WebSocket: Foxglove server on port %d unreachable: %s", self._upstream_port, exc)
            return conn.respond(HTTPStatus.BAD_GATEWAY, "live server unavailable\n")
        self._upstreams[conn] = up
        return None

    def _subprotocol(self, conn: ServerConnection, offered: Sequence[Subprotocol]) -> Subprotocol | None:
        """The subprotocol the SDK chose for this client (one the client offered)."""
        up = self._upstreams.get(conn)
        return up.subprotocol if up is not None else None

    async def _done(self, conn: ServerConnection, request: Request, response: Response) -> None:
        """A handshake that did not switch protocols releases its upstream connection."""
        if response.status_code != HTTPStatus.SWITCHING_PROTOCOLS:
            up = self._upstreams.pop(conn, None)
            if up is not None:
                await up.close()

    async def _relay(self, conn: ServerConnection) -> None:
        up = self._upstreams.pop(conn, None)
        if up is None:
            await conn.close(1011, "no upstream")
            return
        log.info("live WebSocket: client %s connected (%s)", conn.remote_address, conn.subprotocol)

        async def pump(src: ServerConnection | ClientConnection, dst: ServerConnection | ClientConnection) -> None:
            with contextlib.suppress(ConnectionClosed):
                async for message in src:
                    await dst.send(message)

        down_task = asyncio.create_task(pump(up, conn))
        up_task = asyncio.create_task(pump(conn, up))
        try:
            await asyncio.wait({down_task, up_task}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for t in (down_task, up_task):
                t.cancel()
            await asyncio.gather(down_task, up_task, return_exceptions=True)
            # each side ends with the other's close code (1000 when it went away without one)
            code_up = up.close_code if up.close_code is not None else 1000
            code_down = conn.close_code if conn.close_code is not None else 1000
            await up.close(code_down if code_down not in (1005, 1006, 1015) else 1000)
            await conn.close(code_up if code_up not in (1005, 1006, 1015) else 1000, up.close_reason or "")
            log.info("live WebSocket: client %s disconnected", conn.remote_address)

    # the caller's side ----------------------------------------------------------------------------------

    def stop(self) -> None:
        """Close every client and its upstream connection, stop listening and join the thread."""
        with contextlib.suppress(RuntimeError):  # the loop has already ended and closed
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10.0)
        if self._thread.is_alive():
            log.error("live WebSocket gate thread did not stop within 10 s")
        self._sock.close()
