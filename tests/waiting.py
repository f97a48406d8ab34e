"""Waiting in tests: on a condition, with a timeout, never with a bare sleep."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


def wait_until(pred: Callable[[], object], timeout_s: float = 10.0, every_s: float = 0.005) -> bool:
    """Look at ``pred`` every ``every_s`` until it is true (True) or ``timeout_s`` has passed (False)."""
    pause = threading.Event()
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        pause.wait(every_s)
    return False
