"""The live status page for a phone in the car: one HTML page and its JSON, over the standard library's
HTTP server on a thread of its own (the Foxglove SDK's server speaks WebSocket only).

``GET /`` is the page (rendered with the current values, then refreshed by ``fetch`` of
``/status.json`` every second), ``GET /status.json`` the document of
:meth:`rig.live.feed.LiveFeed.status_document`. With a token, every request must carry it
(``?token=…`` or ``Authorization: Bearer …``): 401 otherwise. Big type, black on white, the rollover
warning as a full-width red band: readable in sunlight at arm's length.
"""

from __future__ import annotations

import hmac
import html
import logging
import math
import threading
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import parse_qs, urlsplit

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.relay.endpoints import MASK, Secret
from vsccore.errors import ConfigError

__all__ = ["StatusPage", "render_page"]

log = logging.getLogger(__name__)


def _fmt(x: Any, spec: str, unit: str = "") -> str:
    if not isinstance(x, int | float) or isinstance(x, bool) or not math.isfinite(x):
        return "–"
    return format(x, spec) + unit


def _values(doc: dict[str, Any]) -> dict[str, str]:
    """Field id → text, as the page shows it (the JavaScript below computes the same)."""
    rec = doc.get("recording_s")
    mm, ss = divmod(int(rec), 60) if isinstance(rec, int | float) and math.isfinite(rec) else (0, 0)
    out = {
        "recording": f"{mm:d}:{ss:02d}",
        "disk": _fmt(doc.get("free_disk_mb", math.nan) / 1e3 if isinstance(doc.get("free_disk_mb"), int | float)
                     else math.nan, ".1f", " GB"),
        "corr": _fmt(doc.get("correction_age_s"), ".1f", " s"),
        "baseline": _fmt(doc.get("baseline_m"), ".3f", " m"),
        "nominal": _fmt(doc.get("baseline_nominal_m"), ".3f", " m"),
        "beta_ref": _fmt(doc.get("beta_ref_deg"), "+.2f", "°"),
        "beta_vsc": _fmt(doc.get("beta_vsc_deg"), "+.2f", "°"),
        "speed": _fmt(doc.get("speed_kmh"), ".0f", " km/h"),
        "ltr": _fmt(doc.get("ltr"), "+.2f"),
        "ltr_pred": _fmt(doc.get("ltr_predicted"), "+.2f"),
    }
    for r in doc.get("rovers", []):
        out[f"fix_{r['name']}"] = str(r.get("fix_type", "NONE"))
    return out


_CSS = """
body{margin:0;background:#fff;color:#000;font:bold 7vw/1.15 system-ui,sans-serif}
.row{display:flex;justify-content:space-between;padding:.25em .4em;border-bottom:3px solid #000}
.k{font-weight:600;font-size:.6em;align-self:center}.v{font-variant-numeric:tabular-nums}
.bad{background:#000;color:#ff0}.ok{}
#warn{display:none;background:#d00000;color:#fff;text-align:center;font-size:1.6em;padding:.3em}
#warn.on{display:block}#alarms{font-size:.55em;color:#b00000;padding:.2em .4em}
h1{font-size:.6em;margin:.2em .4em}
"""

_JS = """
const q = location.search;
function fmt(x, d, u, sign) { if (typeof x !== 'number' || !isFinite(x)) return '–';
  const s = x.toFixed(d); return (sign && x >= 0 ? '+' : '') + s + (u || ''); }
function set(id, t) { const e = document.getElementById(id); if (e) e.textContent = t; }
async function tick() {
  try {
    const r = await fetch('status.json' + q, {cache: 'no-store'});
    if (!r.ok) { set('alarms', 'status ' + r.status); return; }
    const d = await r.json();
    const s = Math.floor(d.recording_s || 0);
    set('recording', Math.floor(s / 60) + ':' + String(s % 60).padStart(2, '0'));
    set('disk', fmt((d.free_disk_mb ?? NaN) / 1e3, 1, ' GB'));
    set('corr', fmt(d.correction_age_s, 1, ' s'));
    set('baseline', fmt(d.baseline_m, 3, ' m')); set('nominal', fmt(d.baseline_nominal_m, 3, ' m'));
    document.getElementById('baseline-row').className = 'row ' + (d.baseline_ok ? 'ok' : 'bad');
    set('beta_ref', fmt(d.beta_ref_deg, 2, '°', true)); set('beta_vsc', fmt(d.beta_vsc_deg, 2, '°', true));
    set('speed', fmt(d.speed_kmh, 0, ' km/h'));
    set('ltr', fmt(d.ltr, 2, '', true)); set('ltr_pred', fmt(d.ltr_predicted, 2, '', true));
    document.getElementById('warn').className = d.ltr_warning ? 'on' : '';
    for (const rv of d.rovers || []) {
      set('fix_' + rv.name, rv.fix_type);
      const e = document.getElementById('fixrow_' + rv.name);
      if (e) e.className = 'row ' + (rv.fix_type === 'NARROW_INT' || rv.fix_type === 'L1_INT' ? 'ok' : 'bad');
    }
    set('alarms', (d.alarms || []).join(' · '));
  } catch (e) { set('alarms', 'no connection'); }
}
setInterval(tick, 1000);
"""

_FIXED = ("NARROW_INT", "L1_INT", "WIDE_INT")


def render_page(doc: dict[str, Any]) -> str:
    """The status page with the values of ``doc`` (the script then refreshes them)."""
    v = _values(doc)

    def row(label: str, ident: str, cls: str = "ok", row_id: str = "") -> str:
        rid = f' id="{row_id}"' if row_id else ""
        return (f'<div class="row {cls}"{rid}><span class="k">{html.escape(label)}</span>'
                f'<span class="v" id="{ident}">{html.escape(v.get(ident, "–"))}</span></div>')

    rows = [
        f'<div id="warn" class="{"on" if doc.get("ltr_warning") else ""}">ROLLOVER WARNING</div>',
        f'<h1>vsc-rig live · {html.escape(str(doc.get("session", "")))}</h1>',
    ]
    for r in doc.get("rovers", []):
        name = str(r["name"])
        ok = r.get("fix_type") in _FIXED
        rows.append(row(f"fix {name} ({r.get('antenna', '?')})", f"fix_{name}", "ok" if ok else "bad",
                        f"fixrow_{name}"))
    rows += [
        row("corrections", "corr"),
        row("baseline", "baseline", "ok" if doc.get("baseline_ok") else "bad", "baseline-row"),
        row("configured", "nominal"),
        row("β reference", "beta_ref"),
        row("β VSC", "beta_vsc"),
        row("speed", "speed"),
        row("LTR", "ltr"),
        row("LTR predicted", "ltr_pred"),
        row("recording", "recording"),
        row("free disk", "disk"),
        f'<div id="alarms">{html.escape(" · ".join(doc.get("alarms", [])))}</div>',
    ]
    return ("<!doctype html><html lang=en><head><meta charset=utf-8>"
            '<meta name=viewport content="width=device-width,initial-scale=1">'
            f"<title>vsc-rig live</title><style>{_CSS}</style></head><body>"
            + "".join(rows) + f"<script>{_JS}</script></body></html>")


class StatusPage:
    """The HTTP server of the status page on ``host:port`` (0: any free port), on a thread of its own.

    Raises:
        ConfigError: the address cannot be bound.
    """

    def __init__(self, document: Callable[[], dict[str, Any]], *, host: str, port: int,
                 token: Secret | None = None) -> None:
        self._document = document
        self._token = token
        page = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                page._serve(self)

            def log_message(self, format: str, *args: Any) -> None:
                text = format % args  # the request line: its query carries the token
                if page._token:
                    text = text.replace(page._token.reveal(), MASK)
                log.debug("status page: %s", text)

        try:
            self._httpd = ThreadingHTTPServer((host, port), Handler)
        except OSError as exc:
            raise ConfigError(f"--live-status-port {port} --live-bind {host}: cannot serve the status page: {exc}"
                              ) from exc
        self._httpd.daemon_threads = False  # server_close joins the request threads
        self._thread = threading.Thread(target=self._httpd.serve_forever, name="rig-live-page",
                                        kwargs={"poll_interval": 0.2})
        self._thread.start()

    @property
    def port(self) -> int:
        return int(self._httpd.server_address[1])

    def url(self, host: str, *, reveal: bool = False) -> str:
        """The page's address; with a token, ``?token=***`` unless ``reveal`` (never log a revealed one)."""
        if not self._token:
            return f"http://{host}:{self.port}/"
        return f"http://{host}:{self.port}/?token=" + (self._token.reveal() if reveal else MASK)

    def _authorized(self, req: BaseHTTPRequestHandler) -> bool:
        if not self._token:
            return True
        given = parse_qs(urlsplit(req.path).query).get("token", [""])[0]
        auth = req.headers.get("Authorization", "")
        if auth.startswith("Bearer "):
            given = given or auth.removeprefix("Bearer ").strip()
        return hmac.compare_digest(given.encode(), self._token.reveal().encode())

    def _serve(self, req: BaseHTTPRequestHandler) -> None:
        path = urlsplit(req.path).path
        if path not in ("/", "/status.json"):
            self._send(req, 404, "text/plain; charset=utf-8", b"not found: / or /status.json\n")
            return
        if not self._authorized(req):
            self._send(req, 401, "text/plain; charset=utf-8", b"token required: ?token=...\n")
            return
        doc = self._document()
        if path == "/status.json":
            self._send(req, 200, "application/json", T.encode_record(doc))
        else:
            self._send(req, 200, "text/html; charset=utf-8", render_page(doc).encode())

    @staticmethod
    def _send(req: BaseHTTPRequestHandler, code: int, ctype: str, body: bytes) -> None:
        req.send_response(code)
        req.send_header("Content-Type", ctype)
        req.send_header("Content-Length", str(len(body)))
        req.send_header("Cache-Control", "no-store")
        req.end_headers()
        req.wfile.write(body)

    def stop(self) -> None:
        """Stop serving, close the socket and join the thread."""
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(5.0)
