"""Threads that carry their name into the operating system (``top -H``, ``ps -L``).

Python 3.11 names a thread for itself only; the kernel sees every thread of the daemon as
``ogiflow`` (or ``python``). To see which part of the appliance uses the CPU - the results
thread, the recorder, the live view, a worker process - the names go to the kernel too
(Linux: ``prctl(PR_SET_NAME)``, 15 characters; elsewhere nothing happens).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys
import threading
from typing import Any

_PR_SET_NAME = 15
#: The kernel keeps 15 characters and the terminating zero.
OS_NAME_LENGTH = 15


def _libc() -> Any:
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
    except OSError:
        return None


_LIBC = _libc()


def set_os_thread_name(name: str) -> bool:
    """Give the calling thread ``name`` (cut to 15 characters) in the kernel; True when it
    took (Linux), False elsewhere or when the call failed."""
    if _LIBC is None:
        return False
    raw = name.encode("utf-8", "replace")[:OS_NAME_LENGTH]
    return _LIBC.prctl(_PR_SET_NAME, ctypes.c_char_p(raw), 0, 0, 0) == 0


class NamedThread(threading.Thread):
    """A :class:`threading.Thread` whose name is also its name in the kernel."""

    def run(self) -> None:
        set_os_thread_name(self.name)
        super().run()
