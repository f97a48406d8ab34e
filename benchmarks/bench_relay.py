"""Benchmark of the RTK correction relay: framer speed, sustained throughput and added latency.

Run by hand:  python benchmarks/bench_relay.py [--frames 600] [--rate 50] [--no-str2str]

1. Framer alone: frames/s and MB/s over a long RTCM3 stream fed in 4 kB chunks.
2. Added latency, pseudo-terminal to pseudo-terminal: ``rig relay`` (a separate process, as in
   use) and RTKLIB's ``str2str`` (Debian package ``rtklib``; skipped when absent) relay the same
   stream in the same run: every 1/rate s one MSM7 frame is written to both relays' input ptys;
   the time from the write to the arrival of the frame's last byte on each output pty is the added
   latency (median, 90th, 99th percentile, max).
3. Sustained throughput, pty to pty: frames written as fast as the relay takes them; frames/s and
   kB/s delivered, for both relays.
"""

from __future__ import annotations

import argparse
import os
import select
import shutil
import signal
import statistics
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from drivers.relay.frames import CorrectionFramer, encode_rtcm3  # noqa: E402


def _msm7(number: int, epoch_ms: int, sats: int = 10) -> bytes:
    """An MSM7-sized frame (header bits then filler): what matters here is its size and framing."""
    body = bytearray(18 + 14 * sats)
    body[0] = number >> 4
    body[1] = (number & 0x0F) << 4
    body[2:6] = (epoch_ms & 0x3FFFFFFF).to_bytes(4, "big")
    for i in range(6, len(body)):
        body[i] = (i * 37 + epoch_ms) & 0xFF
    return encode_rtcm3(bytes(body))


class Pty:
    """A pty: the relay opens ``path``; we hold the master (and a slave fd so reads never see EIO)."""

    def __init__(self) -> None:
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)

    def close(self) -> None:
        os.close(self.master)
        os.close(self._slave)


class Reader(threading.Thread):
    """Records (monotonic ns, cumulative bytes) for everything arriving on a pty master."""

    def __init__(self, fd: int) -> None:
        super().__init__(name="bench-reader", daemon=True)
        self.fd = fd
        self.total = 0
        self.marks: list[tuple[int, int]] = []
        self.stop = threading.Event()
        self.cond = threading.Condition()

    def run(self) -> None:
        while not self.stop.is_set():
            r, _, _ = select.select([self.fd], [], [], 0.05)
            if not r:
                continue
            try:
                data = os.read(self.fd, 65536)
            except OSError:
                return
            t = time.monotonic_ns()
            with self.cond:
                self.total += len(data)
                self.marks.append((t, self.total))
                self.cond.notify_all()

    def wait_total(self, n: int, timeout_s: float) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: self.total >= n, timeout_s)

    def arrival(self, end_offset: int) -> int | None:
        for t, total in self.marks:
            if total >= end_offset:
                return t
        return None


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


class RelayUnderTest:
    def __init__(self, name: str, argv_for: object) -> None:
        self.name = name
        self.src = Pty()
        self.dst = Pty()
        self.reader = Reader(self.dst.master)
        self.proc = subprocess.Popen(
            argv_for(self.src.path, self.dst.path),  # type: ignore[operator]
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            cwd=REPO,
            env={**os.environ, "PYTHONPATH": str(REPO)},
        )
        self.reader.start()

    def close(self) -> str:
        self.proc.send_signal(signal.SIGINT)
        try:
            _, err = self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        self.reader.stop.set()
        self.reader.join(2)
        self.src.close()
        self.dst.close()
        return err.decode(errors="replace")


def rig_argv(src: str, dst: str) -> list[str]:
    return [sys.executable, "-m", "rig", "relay", "--from", src, "--to", dst, "--queue", "100000"]


def str2str_argv(src: str, dst: str) -> list[str]:
    return ["str2str", "-in", f"serial://{src[5:]}:115200", "-out", f"serial://{dst[5:]}:115200"]


def bench_framer() -> None:
    frames = [_msm7(1077 + 10 * (i % 4), 1000 * i) for i in range(20000)]
    stream = b"".join(frames)
    framer = CorrectionFramer()
    t = time.perf_counter()
    n = 0
    for i in range(0, len(stream), 4096):
        n += len(framer.feed(stream[i : i + 4096]))
    dt = time.perf_counter() - t
    assert n == len(frames)
    print(f"framer alone: {n / dt:,.0f} frames/s, {len(stream) / dt / 1e6:.1f} MB/s ({len(frames[0])} B frames)")


def warm_up(relays: list[RelayUnderTest]) -> dict[str, int]:
    """Send frames until every relay passes them (a relay may flush its input when it opens the
    port, so bytes sent before then are lost); return each output's byte count once quiet."""
    deadline = time.monotonic() + 60
    frame = _msm7(1005, 0, sats=1)
    while time.monotonic() < deadline:
        for r in relays:
            _write_all(r.src.master, frame)
        if all(r.reader.wait_total(1, 0.1) for r in relays):
            break
    else:
        raise SystemExit("relays did not start within 60 s")
    totals: dict[str, int] = {}
    while True:  # quiet: nothing more arrives for 0.3 s
        before = {r.name: r.reader.total for r in relays}
        time.sleep(0.3)
        totals = {r.name: r.reader.total for r in relays}
        if totals == before:
            return totals


def bench_latency(relays: list[RelayUnderTest], n: int, rate: float) -> None:
    base = warm_up(relays)
    frames = [_msm7(1077, 1000 * k) for k in range(n)]
    sizes = [len(f) for f in frames]
    sent: dict[str, list[int]] = {r.name: [] for r in relays}
    period = 1.0 / rate
    t_next = time.monotonic()
    for k, f in enumerate(frames):
        t_next += period
        order = relays if k % 2 == 0 else relays[::-1]  # alternate who gets the frame first
        for r in order:
            sent[r.name].append(time.monotonic_ns())
            _write_all(r.src.master, f)
        delay = t_next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    for r in relays:
        r.reader.wait_total(base[r.name] + sum(sizes), 10)
    print(f"added latency, pty -> relay -> pty, {n} frames of {sizes[0]} B at {rate:g} Hz:")
    for r in relays:
        lat = []
        end = base[r.name]
        for s, size in zip(sent[r.name], sizes, strict=True):
            end += size
            a = r.reader.arrival(end)
            if a is not None:
                lat.append((a - s) / 1e6)
        if len(lat) < 2:
            print(f"  {r.name:8s}: only {len(lat)} frames arrived")
            continue
        q = statistics.quantiles(lat, n=100)
        print(
            f"  {r.name:8s}: median {statistics.median(lat):6.2f} ms  p90 {q[89]:6.2f} ms  p99 {q[98]:6.2f} ms  "
            f"max {max(lat):6.2f} ms  ({len(lat)}/{n} frames)"
        )


def bench_throughput(relays: list[RelayUnderTest], n: int) -> None:
    frames = b"".join(_msm7(1077 + 10 * (k % 4), 1000 * k) for k in range(n))
    print(f"sustained throughput, pty -> relay -> pty, {n} frames ({len(frames) / 1e3:.0f} kB):")
    for r in relays:
        start = r.reader.total
        t = time.monotonic()
        writer = threading.Thread(target=_write_all, args=(r.src.master, frames), name="bench-writer")
        writer.start()
        ok = r.reader.wait_total(start + len(frames), 60)
        dt = time.monotonic() - t
        writer.join(60)
        got = r.reader.total - start
        print(
            f"  {r.name:8s}: {n * got / len(frames) / dt:9,.0f} frames/s  {got / dt / 1e3:8,.0f} kB/s"
            + ("" if ok else f"  (incomplete: {got}/{len(frames)} B in 60 s)")
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=600, help="frames in the latency run")
    ap.add_argument("--rate", type=float, default=50.0, help="frames per second in the latency run")
    ap.add_argument("--throughput-frames", type=int, default=20000)
    ap.add_argument("--no-str2str", action="store_true")
    args = ap.parse_args()

    bench_framer()
    relays = [RelayUnderTest("rig", rig_argv)]
    if not args.no_str2str:
        if shutil.which("str2str"):
            relays.append(RelayUnderTest("str2str", str2str_argv))
        else:
            print("str2str not found (apt-get install rtklib): comparing nothing")
    try:
        bench_latency(relays, args.frames, args.rate)
        bench_throughput(relays, args.throughput_frames)
    finally:
        for r in relays:
            err = r.close()
            if r.name == "rig":
                summary = [line for line in err.splitlines() if "->" in line or "relay " in line]
                print("rig relay summary: " + " / ".join(s.strip() for s in summary))


if __name__ == "__main__":
    main()
