"""NTRIP 1 and 2 against the simulated caster: data, GGA upload, wrong credentials, unknown mountpoint,
and credentials that never leak into logs, errors, reprs or statistics."""

from __future__ import annotations

import base64
import json
import logging
import random
import threading
import traceback
from collections.abc import Iterator

import pynmea2
import pytest

from drivers.relay import Backoff, CallbackSink, NtripSource, Relay, open_source
from drivers.relay.ntrip import (
    ChunkedDecoder,
    ResponseKind,
    build_gga,
    build_request,
    encode_chunk,
    parse_response_head,
)
from sim_devices.ntrip_caster import NtripCaster
from tests.relay.helpers import base_epoch
from vsccore.errors import NtripAuthError, NtripMountpointError

PASSWORD = "Tr0ub4dor&3-do-not-log"
TOKEN = base64.b64encode(f"alice:{PASSWORD}".encode()).decode()
FAST = Backoff(initial_s=0.05, max_s=0.2)


@pytest.fixture
def caster() -> Iterator[NtripCaster]:
    c = NtripCaster(users={"alice": PASSWORD})
    c.add_mountpoint("BASE1")
    c.add_mountpoint("VRS")
    c.start()
    yield c
    c.stop()


class Collector:
    """A sink callback that keeps frames and signals when ``n`` have arrived."""

    def __init__(self, n: int) -> None:
        self.frames: list[bytes] = []
        self.n = n
        self.done = threading.Event()

    def __call__(self, data: bytes) -> None:
        self.frames.append(data)
        if len(self.frames) >= self.n:
            self.done.set()


@pytest.mark.parametrize("version", [1, 2])
def test_corrections_arrive_through_the_caster(caster: NtripCaster, version: int) -> None:
    epoch = base_epoch()
    got = Collector(2 * len(epoch))
    source = open_source(caster.url("BASE1", "alice", PASSWORD, version=version), env={})
    assert isinstance(source, NtripSource)
    relay = Relay(source, [CallbackSink("rover", got, max_age_s=None)], backoff=FAST)
    relay.start()
    try:
        assert caster.mountpoint("BASE1").wait_for_clients(1, 5)
        mount = caster.mountpoint("BASE1")
        mount.publish(b"".join(epoch))
        # the second epoch in awkward pieces: the chunked coding and the framer must both cope
        stream = b"".join(epoch)
        for i in range(0, len(stream), 37):
            mount.publish(stream[i : i + 37])
        assert got.done.wait(5)
        assert got.frames == epoch + epoch
        assert source.response_version == version
        assert caster.requests[-1] == ("BASE1", version, "data")
        s = relay.stats()
        assert s.frames_by_type["RTCM 1077"] == 2 and s.rejected_frames == 0
    finally:
        relay.stop()


@pytest.mark.parametrize("version", [1, 2])
def test_gga_is_uploaded_periodically(caster: NtripCaster, version: int) -> None:
    position = (52.123456789, -13.987654321, 87.5)
    source = open_source(
        caster.url("VRS", "alice", PASSWORD, version=version), env={}, gga=lambda: position, gga_period_s=0.1
    )
    relay = Relay(source, [], backoff=FAST)
    relay.start()
    try:
        assert caster.wait_for_gga(3, timeout_s=5)
    finally:
        relay.stop()
    records = [g for g in caster.gga_received if g.mountpoint == "VRS"]
    assert records[0].user == "alice"
    assert records[0].via_header == (version == 2)  # NTRIP 2 carries the first one in Ntrip-GGA
    for rec in records:
        msg = pynmea2.parse(rec.sentence)  # checksum verified by pynmea2
        assert isinstance(msg, pynmea2.GGA)
        assert msg.latitude == pytest.approx(position[0], abs=1e-7)
        assert msg.longitude == pytest.approx(position[1], abs=1e-7)
        assert float(msg.altitude) == pytest.approx(position[2], abs=1e-3)


@pytest.mark.parametrize("version", [1, 2])
def test_wrong_password_is_a_clear_error_without_retry_storm(
    caster: NtripCaster, version: int, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    wrong = "wrong-" + PASSWORD
    relay = Relay(open_source(caster.url("BASE1", "alice", wrong, version=version), env={}), [], backoff=FAST)
    relay.start()
    try:
        assert relay.wait(5)  # the relay gives up by itself: retrying would not help
        assert isinstance(relay.error, NtripAuthError)
        text = str(relay.error)
        assert "127.0.0.1" in text and "BASE1" in text and "alice" in text and "401" in text
        assert relay.stats().state == "failed"
    finally:
        relay.stop()
    assert caster.unauthorized == 1
    for secret in (wrong, PASSWORD, base64.b64encode(f"alice:{wrong}".encode()).decode()):
        assert secret not in text
        assert secret not in repr(relay.error)
        assert secret not in caplog.text


@pytest.mark.parametrize("version", [1, 2])
def test_unknown_mountpoint_lists_the_source_table(caster: NtripCaster, version: int) -> None:
    relay = Relay(open_source(caster.url("NOPE", "alice", PASSWORD, version=version), env={}), [], backoff=FAST)
    relay.start()
    try:
        assert relay.wait(5)
    finally:
        relay.stop()
    assert isinstance(relay.error, NtripMountpointError)
    assert "NOPE" in str(relay.error)
    assert "BASE1, VRS" in str(relay.error)
    assert PASSWORD not in str(relay.error)


def test_credentials_never_leak(caster: NtripCaster, caplog: pytest.LogCaptureFixture) -> None:
    """Run a session with reconnects and a GGA upload at DEBUG level; look for the password and its
    Basic-auth token in everything a person or a file could see."""
    caplog.set_level(logging.DEBUG)
    epoch = base_epoch()
    got = Collector(len(epoch))
    url = caster.url("BASE1", "alice", PASSWORD)
    source = open_source(url, env={}, gga=lambda: (48.0, 11.0, 500.0), gga_period_s=0.1)
    assert isinstance(source, NtripSource)
    relay = Relay(source, [CallbackSink("rover", got)], backoff=FAST)
    relay.start()
    try:
        assert caster.mountpoint("BASE1").wait_for_clients(1, 5)
        caster.mountpoint("BASE1").publish(b"".join(epoch))
        assert got.done.wait(5)
        assert caster.wait_for_gga(2, 5)
        seen = [
            repr(relay),
            repr(source),
            str(source.name),
            repr(source.endpoint),
            repr(relay.stats()),
            json.dumps(relay.stats().to_topic_dict()),
        ]
    finally:
        relay.stop()
    # an error path too: the caster is gone, the source reports connection errors
    failing = open_source(url.replace(str(caster.port), "1"), env={})
    with pytest.raises(OSError) as excinfo:
        failing.open()
    seen += [str(excinfo.value), repr(excinfo.value), "".join(traceback.format_exception(excinfo.value))]
    seen.append(caplog.text)
    for text in seen:
        assert PASSWORD not in text
        assert TOKEN not in text


def test_chunked_decoder_any_split() -> None:
    rng = random.Random(7)
    payload = bytes(rng.randrange(256) for _ in range(3000))
    coded = b"".join(encode_chunk(payload[i : i + n]) for i, n in _pieces(len(payload), rng)) + b"0\r\n\r\n"
    for _ in range(20):
        dec = ChunkedDecoder()
        out = b""
        pos = 0
        while pos < len(coded):
            step = rng.randrange(1, 50)
            out += dec.feed(coded[pos : pos + step])
            pos += step
        assert out == payload
        assert dec.done


def _pieces(total: int, rng: random.Random) -> Iterator[tuple[int, int]]:
    i = 0
    while i < total:
        n = rng.randrange(1, 400)
        yield i, min(n, total - i)
        i += n


def test_response_heads() -> None:
    icy = parse_response_head(b"ICY 200 OK\r\n\xd3\x00")
    assert icy is not None and icy.kind is ResponseKind.DATA and icy.body_start == 12
    assert parse_response_head(b"HTTP/1.1 200 OK\r\nNtrip-Version: Ntrip/2.0\r\n") is None
    v2 = parse_response_head(b"HTTP/1.1 200 OK\r\nNtrip-Version: Ntrip/2.0\r\nTransfer-Encoding: chunked\r\n\r\nA\r\n")
    assert v2 is not None and v2.kind is ResponseKind.DATA and v2.version == 2 and v2.chunked
    table = parse_response_head(b"HTTP/1.1 200 OK\r\nContent-Type: gnss/sourcetable\r\n\r\nSTR;X")
    assert table is not None and table.kind is ResponseKind.SOURCETABLE
    denied = parse_response_head(b"HTTP/1.0 401 Unauthorized\r\n\r\n")
    assert denied is not None and denied.kind is ResponseKind.UNAUTHORIZED


def test_requests() -> None:
    v1 = build_request("h", 2101, "M", user="u", password="p", version=1)
    assert v1.startswith(b"GET /M HTTP/1.0\r\n") and b"Ntrip-Version" not in v1
    assert b"Authorization: Basic " + base64.b64encode(b"u:p") + b"\r\n" in v1
    gga = build_gga(1.5, 2.5, 3.0, utc_seconds_of_day=3723.5)
    v2 = build_request("h", 2101, "M", user=None, password=None, version=2, gga=gga)
    assert v2.startswith(b"GET /M HTTP/1.1\r\nHost: h:2101\r\nNtrip-Version: Ntrip/2.0\r\n")
    assert b"Authorization" not in v2 and f"Ntrip-GGA: {gga}\r\n".encode() in v2
    assert v2.endswith(b"\r\n\r\n")
    msg = pynmea2.parse(gga)
    assert msg.timestamp.hour == 1 and msg.timestamp.minute == 2 and msg.timestamp.second == 3
