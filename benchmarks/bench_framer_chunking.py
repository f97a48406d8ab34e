"""Cost of the NovAtel framer against the size of the chunks it is fed.

A serial port at 460 800 baud delivers 1–64 bytes per read, so :class:`drivers.novatel.Framer`
must cost the same per byte however the stream is chunked. This feeds 1 MB of a receiver stream
once in one call and once in chunks of 64, 16, 4 and 1 byte(s), and prints the CPU time of each
and its ratio to the one-call figure. Goal: 1 MB fed one byte at a time within 3x the one call.

Two streams:

- ``receiver``: what a rover port carries: binary BESTPOS/BESTVEL at 20 Hz (most bytes), ASCII
  BESTVEL, NMEA GGA, RTCM3 1005, abbreviated-ASCII logs, ``<OK`` responses and port prompts.
- ``worst``: the shapes that used to be quadratic: abbreviated logs of 400 short continuation
  lines, ASCII candidates that run 20 000 bytes without their ``*``, a long binary log, a long
  binary log whose CRC fails (the search resumes inside it, among bytes of every value) and a run
  of bytes that start no frame.

CPU time of the process (``time.process_time``; the machine is shared). Each round runs every
chunking in turn (so a change of load hits them all alike); a time is the median over ``--rounds``
rounds, a ratio is taken per round against that round's one call and shown as min/median/max over
the rounds, with the ratio of the quietest rounds (minimum time over minimum time) beside it. The
frames and the counts of every chunking are checked to equal the one-call result. Two floors show
what the per-call Python cost alone comes to: a ``feed`` that does nothing, and one that only
appends the chunk to a bytearray (any framer must keep the bytes of a frame it has not finished),
both through the same loop, returning the framer's empty result (the shared empty tuple). When the
one call costs less than these floors' 3x (the ``worst`` stream: most of its bytes are passed over
by one C-level search or CRC in one call), no feed written in Python meets the goal on it; the
floors say by how much.

``Framer.feed``'s per-chunk entry is C (drivers/novatel/_feed.c) where the extension is built; ``--feed
python`` measures its pure-Python twin (what an install without a C compiler runs) on the same streams.

Measured on an idle 2-CPU machine (2026-12-03, 9 rounds): ``receiver`` 1-byte feed median **2.14x** one
call with the C entry (per-round 1.59-2.25x; goal met), 3.67x with the Python twin (the no-op floor
0.85x, the append-only floor 1.44x: a Python feed cannot get far under 3x). Under the load of a running
test suite: 2.04x (C). ``worst``: 5.0x with the C entry, 10.3x with the Python twin (its one call passes
over most bytes in one C-level search or CRC; its 1-byte feed wakes a Python look at each of its 400-line
abbreviated logs' line ends): linear, not within 3x.

Run::

    python benchmarks/bench_framer_chunking.py [--mb 1] [--rounds 5]
"""

from __future__ import annotations

import argparse
import gc
import statistics
import struct
import time

from drivers.novatel import (
    BestPos,
    BestVel,
    Datum,
    Frame,
    Framer,
    PositionType,
    SolutionStatus,
    encode_abbreviated,
    encode_ascii,
    encode_binary,
    encode_ok,
    encode_prompt,
    make_header,
    xor_checksum,
)
from drivers.novatel.crc import crc24q, novatel_crc32
from drivers.novatel.framer import FEED_IMPLEMENTATION, _PyFeedGate

GOAL_RATIO = 3.0


def _bestpos(i: int) -> BestPos:
    return BestPos(
        SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, 48.1173 + i * 1e-7, 11.5167, 545.4, 46.9, Datum.WGS84,
        0.012, 0.011, 0.021, "131", 1.0, 0.0, 20, 18, 18, 16, 0, 0x02, 0x11, 0x33,
    )


def _gga(i: int) -> bytes:
    body = f"GPGGA,{120000 + i % 40000:06d}.00,4807.038,N,01131.000,E,4,18,0.9,545.4,M,46.9,M,1.0,0131"
    return f"${body}*{xor_checksum(body.encode()):02X}\r\n".encode()


def _rtcm_1005() -> bytes:
    # Station 2003 antenna reference point (bits packed by hand: 152-bit payload of message 1005).
    bits = "".join(
        format(v & ((1 << w) - 1), f"0{w}b")
        for v, w in [(1005, 12), (2003, 12), (0, 6), (1, 1), (0, 1), (0, 1), (0, 1), (41770001234, 38), (0, 1),
                     (0, 1), (8550005678, 38), (0, 2), (47270009000, 38)]
    )
    payload = int(bits, 2).to_bytes(len(bits) // 8, "big")
    frame = bytes([0xD3, len(payload) >> 8, len(payload) & 0xFF]) + payload
    return frame + crc24q(frame).to_bytes(3, "big")


def _long_binary(body_len: int) -> bytes:
    # A long-header log with a message ID the decoder does not know: framed and CRC-checked only.
    header = struct.pack("<3BBHbBHHBBHlLHH", 0xAA, 0x44, 0x12, 28, 9999, 0, 32, body_len, 0, 0, 180, 2300, 345600000,
                         0, 0, 0)
    frame = header + bytes(range(256)) * (body_len // 256) + bytes(body_len % 256)
    return frame + struct.pack("<I", novatel_crc32(frame))


def receiver_stream(size: int) -> bytes:
    parts: list[bytes] = []
    total = 0
    i = 0
    vel = BestVel(SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, 0.05, 1.0, 13.5, 87.25, -0.02, 0.0)
    rtcm = _rtcm_1005()
    while total < size:
        pos = _bestpos(i)
        head = make_header(pos, week=2300, seconds=345600.0 + i * 0.05, port="COM1", sequence=i % 100)
        vhead = make_header(vel, week=2300, seconds=345600.0 + i * 0.05, port="COM1")
        chunk = [encode_binary(head, pos), encode_binary(vhead, vel)]
        if i % 20 == 0:
            chunk += [encode_ascii(vhead, vel), _gga(i), rtcm]
        if i % 100 == 0:
            chunk += [encode_abbreviated(head, pos), encode_ok(), encode_prompt("COM1")]
        for c in chunk:
            parts.append(c)
            total += len(c)
        i += 1
    return b"".join(parts)[:size]


def worst_stream(size: int) -> bytes:
    pos = _bestpos(0)
    head = make_header(pos, week=2300, seconds=345600.0, port="COM1")
    abbrev_header = encode_abbreviated(head, pos).split(b"\r\n", 1)[0] + b"\r\n"
    pieces = [
        abbrev_header + b"<     1\r\n" * 400,
        b"#BESTPOSA,COM1," + b"x" * 20000 + b"\r\n",
        _long_binary(16000),
        _long_binary(8000)[:-1] + b"\x00",  # its CRC fails
        b"\x00" * 2000,
    ]
    unit = b"".join(pieces)
    return (unit * (size // len(unit) + 1))[:size]


class _NoFramer:
    """The floor: a ``feed`` that does nothing (and returns what the framer returns when no frame
    completes: the empty tuple)."""

    def feed(self, data: bytes) -> tuple[object, ...]:
        return ()

    def finish(self) -> tuple[object, ...]:
        return ()


class _AppendOnly(_NoFramer):
    """The floor of holding the bytes: a ``feed`` that appends the chunk to a bytearray."""

    def __init__(self) -> None:
        self._acc = bytearray()

    def feed(self, data: bytes) -> tuple[object, ...]:
        acc = self._acc
        acc += data
        return ()


def _time(framer: Framer | _NoFramer, chunks: list[bytes]) -> tuple[float, list[object]]:
    feed = framer.feed
    frames: list[object] = []
    gc.collect()  # the previous run's garbage is not this run's cost
    t0 = time.process_time()
    for chunk in chunks:
        frames += feed(chunk)
    frames += framer.finish()
    return time.process_time() - t0, frames


#: The framer measured: the install's (``--feed installed``) or the one with the pure-Python feed.
FRAMER: type[Framer] = Framer


def run(chunks: list[bytes]) -> tuple[float, list[tuple[object, bytes]], dict[str, object]]:
    """CPU time of feeding ``chunks`` (already cut, as a port's reads deliver them) and finishing."""
    framer = FRAMER()
    elapsed, frames = _time(framer, chunks)
    return elapsed, [(f.kind, f.raw) for f in frames if isinstance(f, Frame)], framer.stats.to_dict()


def measure(name: str, data: bytes, rounds: int) -> float:
    """Print the figures of one stream; return the 1-byte ratio (median of per-round ratios)."""
    sizes = (len(data), 64, 16, 4, 1)
    cut = {chunk: [data[i : i + chunk] for i in range(0, len(data), chunk)] for chunk in sizes}
    # The chunk lists (a million items) stay out of the collector's full passes, which would otherwise
    # charge their traversal to whichever run they happen in.
    gc.freeze()
    reference: tuple[list[tuple[object, bytes]], dict[str, object]] | None = None
    times: dict[object, list[float]] = {key: [] for key in (*sizes, "noop", "append")}
    for _ in range(rounds):
        for chunk in sizes:
            elapsed, frames, stats = run(cut[chunk])
            times[chunk].append(elapsed)
            if reference is None:
                reference = (frames, stats)
            elif (frames, stats) != reference:
                raise SystemExit(f"{name}: chunks of {chunk} B give other frames or counts than one call")
        times["noop"].append(_time(_NoFramer(), cut[1])[0])
        times["append"].append(_time(_AppendOnly(), cut[1])[0])
    assert reference is not None
    one = times[len(data)]

    def ratio(key: object) -> tuple[list[float], float]:
        """Per-round ratios to the one call, sorted; the quietest rounds' ratio."""
        return sorted(t / o for t, o in zip(times[key], one, strict=True)), min(times[key]) / min(one)

    def spread(ratios: list[float]) -> str:
        return f"{ratios[0]:5.2f} / {statistics.median(ratios):5.2f} / {ratios[-1]:5.2f}x"

    print(f"{name}: {len(data) / 1e6:.2f} MB, {len(reference[0])} frames, {rounds} rounds;"
          " ratios to one call: min / median / max over rounds")
    for chunk in sizes:
        t = statistics.median(times[chunk])
        label = "one call" if chunk == len(data) else f"{chunk:>3} B chunks"
        ratios, quiet = ratio(chunk)
        print(f"  {label:>13}: {t:7.3f} s CPU  ({len(data) / t / 1e6:6.2f} MB/s)  {spread(ratios)}"
              f"  (quietest rounds {quiet:5.2f}x)")
    for key, what in (("noop", "a no-op feed per byte"), ("append", "a feed that only appends the byte")):
        ratios, quiet = ratio(key)
        print(f"  floor, {what}: {statistics.median(times[key]):.3f} s CPU = {spread(ratios)}"
              f"  (quietest rounds {quiet:.2f}x)")
    gc.unfreeze()
    median = statistics.median(ratio(1)[0])
    print(f"  goal: 1-byte feed <= {GOAL_RATIO:.0f}x one call (median): {'met' if median <= GOAL_RATIO else 'NOT met'}")
    return median


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mb", type=float, default=1.0, help="stream size in MB (default 1)")
    parser.add_argument("--rounds", type=int, default=5, help="rounds; medians are shown (default 5)")
    parser.add_argument("--feed", choices=("installed", "python"), default="installed",
                        help="the install's Framer.feed (C where built) or its pure-Python twin")
    args = parser.parse_args()
    global FRAMER
    if args.feed == "python":
        FRAMER = type("PyFeedFramer", (Framer,), {"feed": _PyFeedGate.feed})
    print(f"Framer.feed: {FEED_IMPLEMENTATION if args.feed == 'installed' else 'python'}")
    size = int(args.mb * 1_000_000)
    verdicts = []
    for name, data in (("receiver", receiver_stream(size)), ("worst", worst_stream(size))):
        verdicts.append(f"{name} {measure(name, data, args.rounds):.2f}x")
    print("summary: 1-byte feed / one call: " + ", ".join(verdicts))


if __name__ == "__main__":
    main()
