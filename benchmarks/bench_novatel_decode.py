"""Decoding rate of the NovAtel codec against pynmea2, in the same run.

Measures messages/s of a full decode (framing, CRC, header and every body field into frozen
dataclasses) of BESTPOS through :class:`drivers.novatel.Framer` on one large buffer, in binary
(BESTPOSB, 104 bytes) and in ASCII (BESTPOSA, ~200 characters), and compares it with pynmea2 on
GGA sentences:

- ``pynmea2.parse`` on pre-split lines (pynmea2 splits the fields and converts them lazily, so
  this is its least work per sentence: the baseline the goal refers to),
- ``pynmea2.parse`` plus reading the GGA values (time, lat, lon, altitude, quality, satellites,
  HDOP, geoid separation) so that both sides end with converted numbers.

The machine is shared, so each figure is the best of several interleaved rounds. Run::

    python benchmarks/bench_novatel_decode.py [--messages 20000] [--rounds 7]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import pynmea2

from drivers.novatel import (
    BestPos,
    Datum,
    Framer,
    PositionType,
    SolutionStatus,
    TimeStatus,
    encode_ascii,
    encode_binary,
    make_header,
)


def _bestpos(i: int) -> BestPos:
    return BestPos(
        sol_status=SolutionStatus.SOL_COMPUTED,
        pos_type=PositionType.NARROW_INT,
        lat_deg=51.15043874397 + i * 1e-9,
        lon_deg=-114.03066788586 - i * 1e-9,
        hgt_m=1097.6822 + (i % 100) * 1e-3,
        undulation_m=-17.0,
        datum=Datum.WGS84,
        lat_sigma_m=0.0123,
        lon_sigma_m=0.0098,
        hgt_sigma_m=0.0211,
        stn_id="131",
        diff_age_s=1.0,
        sol_age_s=0.0,
        num_svs=24,
        num_soln_svs=22,
        num_soln_l1_svs=22,
        num_soln_multi_svs=20,
        reserved=0,
        ext_sol_stat=0x02,
        galileo_beidou_sig_mask=0x11,
        gps_glonass_sig_mask=0x33,
    )


def _stream(n: int, encode: Callable[..., bytes]) -> bytes:
    parts = []
    for i in range(n):
        body = _bestpos(i)
        header = make_header(
            body, week=2300, seconds=345600.0 + i * 0.05, port="COM1", sequence=0, idle_time_pct=80.0,
            time_status=TimeStatus.FINESTEERING, receiver_status=0x02000000, reserved=0xB1F6, sw_version=16248,
        )
        parts.append(encode(header, body))
    return b"".join(parts)


def _gga_lines(n: int) -> list[str]:
    lines = []
    for i in range(n):
        hh, rem = divmod(i, 3600)
        mm, ss = divmod(rem, 60)
        body = (
            f"GPGGA,{hh % 24:02d}{mm:02d}{ss:02d}.00,5109.0262{i % 10:01d},N,11401.8407{i % 7:01d},W,4,22,0.7,"
            f"1097.682,M,-17.000,M,1.0,0131"
        )
        checksum = 0
        for ch in body.encode():
            checksum ^= ch
        lines.append(f"${body}*{checksum:02X}")
    return lines


def _rate(fn: Callable[[], int]) -> float:
    t0 = time.perf_counter()
    count = fn()
    return count / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--messages", type=int, default=20000, help="messages per buffer")
    parser.add_argument("--rounds", type=int, default=7, help="interleaved rounds (best is kept)")
    args = parser.parse_args()
    n = args.messages

    binary = _stream(n, encode_binary)
    ascii_ = _stream(n, encode_ascii)
    gga = _gga_lines(n)

    def run_binary() -> int:
        frames = Framer().feed(binary)
        assert len(frames) == n and isinstance(frames[-1].message.body, BestPos)
        return len(frames)

    def run_ascii() -> int:
        frames = Framer().feed(ascii_)
        assert len(frames) == n and isinstance(frames[-1].message.body, BestPos)
        return len(frames)

    def run_pynmea2() -> int:
        parse = pynmea2.parse
        out = [parse(line) for line in gga]
        return len(out)

    def run_pynmea2_values() -> int:
        parse = pynmea2.parse
        count = 0
        for line in gga:
            m = parse(line)
            _ = (m.timestamp, m.latitude, m.longitude, m.altitude, m.gps_qual, m.num_sats, m.horizontal_dil)
            _ = float(m.geo_sep)
            count += 1
        return count

    cases = {
        "novatel BESTPOSB (binary) via Framer": run_binary,
        "novatel BESTPOSA (ASCII) via Framer": run_ascii,
        "pynmea2.parse GGA (lazy fields)": run_pynmea2,
        "pynmea2.parse GGA + read values": run_pynmea2_values,
    }
    best = dict.fromkeys(cases, 0.0)
    for _ in range(args.rounds):
        for name, fn in cases.items():
            best[name] = max(best[name], _rate(fn))

    print(f"messages per buffer: {n}; best of {args.rounds} interleaved rounds")
    print(f"  BESTPOSB frame {len(binary) // n} bytes, BESTPOSA line {len(ascii_) // n} bytes, "
          f"GGA line {sum(map(len, gga)) // n + 2} bytes")
    for name, rate in best.items():
        print(f"  {name:40s} {rate:12,.0f} msg/s")
    base = best["pynmea2.parse GGA (lazy fields)"]
    full = best["pynmea2.parse GGA + read values"]
    for name in ("novatel BESTPOSB (binary) via Framer", "novatel BESTPOSA (ASCII) via Framer"):
        rate = best[name]
        print(f"  {name:40s} {rate / base:5.2f}x pynmea2.parse, {rate / full:5.2f}x pynmea2 parse+values")
    goal = 2.0
    ok = best["novatel BESTPOSB (binary) via Framer"] / base >= goal
    print(f"  goal >= {goal:.0f}x pynmea2.parse (binary): {'met' if ok else 'NOT met'}")
    if not math.isfinite(base):
        raise SystemExit("pynmea2 rate not measured")


if __name__ == "__main__":
    main()
