"""What a simulated port's reader still owes (the governed clock stands still until it has read)."""

from __future__ import annotations

import os
from pathlib import Path

from sim_devices.gnss.pty import PtyPort


def test_unread_counts_every_byte_the_reader_has_not_read() -> None:
    """Issue 15: the line discipline's FIONREAD misses the bytes still in the pty's flip buffers (a kernel
    worker moves them later: on a busy host 12 KB written read as 0 unread) and saturates at 4 KB, so
    the governed clock took writes nobody had read as read and ran on; the reader fell behind, the pty
    filled and the receivers' logs were dropped silently (0.3-0.4 s of both rovers in a stressed demo)."""
    port = PtyPort("COM1", Path(os.environ.get("TMPDIR", "/tmp")) / f"vsc-test-pty-{os.getpid()}")
    port.plug()
    try:
        assert port.device_path is not None
        reader = os.open(port.device_path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
        try:
            assert port.unread() == 0
            written = 0
            for _ in range(10):  # 10 KB: more than the line discipline holds, within the pty's buffers
                written += port.write(b"x" * 1000)
                assert port.unread() == written  # old: 0 right after a write (flip buffer), then at most 4095
            assert written == 10_000 and port.bytes_dropped == 0
            got = os.read(reader, 3000)  # a partial read: the rest is still owed
            assert 0 < len(got) <= 3000 and port.unread() == written
            while True:
                try:
                    if not os.read(reader, 65536):
                        break
                except BlockingIOError:
                    if port.unread() == 0:  # (flushing the flip buffers may move more in: read again)
                        break
            assert port.unread() == 0
            port.write(b"y" * 100)
            assert port.unread() == 100
        finally:
            os.close(reader)
    finally:
        port.unplug()
