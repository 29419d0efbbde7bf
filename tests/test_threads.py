"""The daemon's threads carry their names into the kernel (Linux: ``top -H``, ``ps -L``)."""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import pytest

from appliance.threads import OS_NAME_LENGTH, NamedThread, set_os_thread_name

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="thread names in the kernel: Linux only (prctl)")


def _kernel_name(native_id: int) -> str:
    return Path(f"/proc/self/task/{native_id}/comm").read_text().strip()


@pytest.mark.parametrize("name", ["results", "a-name-longer-than-fifteen"])
def test_named_thread_shows_its_name_to_the_kernel(name: str) -> None:
    seen: list[str] = []

    def body() -> None:
        seen.append(_kernel_name(threading.get_native_id()))

    t = NamedThread(target=body, name=name, daemon=True)
    t.start()
    t.join(timeout=10)
    assert seen == [name[:OS_NAME_LENGTH]]


def test_a_plain_thread_keeps_the_process_name_and_set_name_changes_it() -> None:
    seen: list[str] = []

    def body() -> None:
        before = _kernel_name(threading.get_native_id())
        assert set_os_thread_name("renamed")
        seen.extend([before, _kernel_name(threading.get_native_id())])

    t = threading.Thread(target=body, name="plain-thread", daemon=True)
    t.start()
    t.join(timeout=10)
    assert seen[0] != "plain-thread" and seen[1] == "renamed"
