"""The systemd unit: `systemd-analyze verify` must print nothing, and the policy is as documented.

Needs the Debian package `systemd` (for systemd-analyze); `tools/install.sh --dev` installs it.
"""

from __future__ import annotations

import configparser
import re
import shutil
import subprocess
from pathlib import Path

import pytest

UNIT = Path(__file__).resolve().parents[1] / "systemd" / "ogiflow.service"
EXEC = "/opt/ogiflow/.venv/bin/ogiflow"


def _analyze() -> str:
    exe = shutil.which("systemd-analyze")
    assert exe, "systemd-analyze missing: install the Debian package systemd " \
                "(tools/install.sh --dev does)"
    return exe


def _verify(text: str, tmp_path: Path) -> str:
    """Run `systemd-analyze verify` on a copy whose ExecStart points at an existing
    executable (the real path exists only on an installed appliance)."""
    fake = tmp_path / "ogiflow"
    fake.write_text("#!/bin/sh\nexit 0\n")
    fake.chmod(0o755)
    unit = tmp_path / "ogiflow.service"
    unit.write_text(text.replace(EXEC, str(fake)))
    out = subprocess.run([_analyze(), "verify", str(unit)], capture_output=True, text=True,
                         timeout=60)
    return (out.stdout + out.stderr).strip()


def test_systemd_analyze_verify_prints_nothing(tmp_path: Path) -> None:
    text = UNIT.read_text()
    assert EXEC in text
    assert _verify(text, tmp_path) == ""


def test_verify_would_catch_a_typo(tmp_path: Path) -> None:
    """The check above can fail: systemd-analyze exits 0 on unknown keys but prints them."""
    text = UNIT.read_text().replace("WatchdogSec=", "WatchDogSec=")
    assert "WatchDogSec" in _verify(text, tmp_path)


@pytest.mark.parametrize(("key", "value"), [
    ("Type", "notify"),
    ("NotifyAccess", "main"),
    ("WatchdogSec", "30"),
    ("Restart", "on-failure"),
    ("RestartPreventExitStatus", "2"),
    ("User", "ogiflow"),
    ("SupplementaryGroups", "dialout"),
    ("ProtectSystem", "strict"),
    ("ReadWritePaths", "/var/lib/ogiflow"),
    ("NoNewPrivileges", "yes"),
    ("PrivateTmp", "yes"),
    ("ProtectHome", "yes"),
    ("ExecStart", f"{EXEC} run --config /etc/ogiflow/site.yaml"),
])
def test_unit_policy(key: str, value: str) -> None:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read_string(UNIT.read_text())
    assert parser["Service"][key] == value


def test_stop_timeout_leaves_room_for_the_5_s_shutdown() -> None:
    text = UNIT.read_text()
    stop = int(text.split("TimeoutStopSec=")[1].split()[0])
    assert stop >= 10


def exposure(unit: Path) -> float:
    """The overall exposure score of `systemd-analyze security --offline=true` (0-10)."""
    out = subprocess.run([_analyze(), "security", "--offline=true", str(unit)],
                         capture_output=True, text=True, timeout=60)
    for line in (out.stdout + out.stderr).splitlines():
        if "Overall exposure level" in line:
            return float(line.split(":")[1].split()[0])
    raise AssertionError(f"no exposure score in: {out.stdout}{out.stderr}")


def test_exposure_score_is_at_most_2(tmp_path: Path) -> None:
    """The hardening keeps the unit at <= 2.0."""
    assert exposure(UNIT) <= 2.0
    weakened = tmp_path / "ogiflow.service"
    text = UNIT.read_text()
    weakened.write_text("\n".join(line for line in text.splitlines()
                                  if not line.startswith(("SystemCallFilter", "IPAddress",
                                                          "ProtectProc", "ProcSubset"))))
    assert exposure(weakened) > 2.0  # the check can fail


def test_ring_and_serial_still_allowed_by_the_filters() -> None:
    """What the appliance needs stays open: /dev/shm (ring), the serial ports, the network."""
    text = UNIT.read_text()
    assert "RemoveIPC=yes" in text
    assert not re.search(r"^PrivateDevices=yes", text, re.M)
    for dev in ("char-ttyS", "char-ttyUSB", "char-ttyACM"):
        assert f"DeviceAllow={dev} rw" in text
    assert "RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_NETLINK" in text
    assert "MemoryDenyWriteExecute=yes" not in text  # numba compiles at run time
