"""foxglove-sdk's tokio workers against the suite's thread-leak check (tests/conftest.py).

The SDK runs one tokio runtime per process, whose workers never end. When a worker logs through
Python's ``logging`` ("Dropping client …: handshake failed", "Shutdown complete", possibly after the
server's own test has ended), Python registers it as a ``_DummyThread``: alive for good and not
joinable. The leak check used to join it (``AssertionError: cannot join a dummy thread``) in whichever
test was running, which is why live tests, and the test after one, failed inside the full suite and
passed alone. The check runs here in a fresh interpreter, so the workers are new whatever ran before.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

INNER = '''
import logging
import socket

from rig.live.server import FoxgloveSink
from tests.conftest import _no_thread_leaks  # noqa: F401 - the suite's autouse leak check, for this module


def test_sdk_workers_log_into_python():
    logging.getLogger("foxglove").setLevel(logging.INFO)
    sink = FoxgloveSink(host="127.0.0.1", port=0, name="leak-check")
    try:
        for _ in range(8):  # not a WebSocket upgrade: a worker logs "Dropping client ...: handshake failed"
            with socket.create_connection(("127.0.0.1", sink.port), timeout=5.0) as c:
                c.sendall(b"GET / HTTP/1.1\\r\\nHost: x\\r\\n\\r\\n")
                c.recv(1024)
    finally:
        sink.stop()


def test_a_real_leak_is_still_caught():
    import threading
    stop = threading.Event()
    threading.Thread(target=stop.wait, args=(10.0,), name="leaky", daemon=True).start()
'''


def test_sdk_runtime_workers_are_not_leaks_but_python_threads_still_are(tmp_path: Path) -> None:
    (tmp_path / "test_inner.py").write_text(INNER)
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-o", "addopts=",
                        "--rootdir", str(tmp_path), str(tmp_path / "test_inner.py")],
                       cwd=REPO, capture_output=True, text=True, timeout=180,
                       env={**os.environ, "PYTHONPATH": str(REPO)})
    out = r.stdout + r.stderr
    assert "cannot join a dummy thread" not in out, out
    assert "2 passed, 1 error" in out, out  # both calls pass; the leaky test errs at its teardown, the SDK one not
    assert "test leaked running threads: ['leaky']" in out, out
