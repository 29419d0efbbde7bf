"""Fault injectors shared by the fault-injection tests (a full disk, a stepped wall clock)."""

from __future__ import annotations

import errno
import io
import shutil
import threading
from pathlib import Path
from typing import Any

import pytest

from appliance.recording import files


class FullDisk:
    """While ``full`` is set, every write of the recorder's files fails with ENOSPC and the
    recording directory reports no free space; clear it and the space is back.

    Installed with ``monkeypatch``: the recorder opens its files through ``files.open`` and
    checks space with ``shutil.disk_usage``, the same calls a real full disk fails in.
    """

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.full = threading.Event()
        self.failed_writes = 0
        disk = self

        class Writer(io.BufferedWriter):
            def write(self, data: Any) -> int:
                if disk.full.is_set():
                    disk.failed_writes += 1
                    raise OSError(errno.ENOSPC, "No space left on device")
                return super().write(data)

        def fake_open(path: Path, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
            if mode == "xb":
                if disk.full.is_set():
                    raise OSError(errno.ENOSPC, "No space left on device", str(path))
                return Writer(io.FileIO(path, "x"))
            return open(path, mode, *args, **kwargs)

        real_usage = shutil.disk_usage

        def usage(path: Any) -> Any:
            u = real_usage(path)
            return type(u)(u.total, u.total, 0) if disk.full.is_set() else u

        monkeypatch.setattr(files, "open", fake_open, raising=False)
        monkeypatch.setattr(shutil, "disk_usage", usage)
