"""numba's cache in one folder per version of the numerical code (processing/kernel_cache.py).

numba checks only a kernel's own file when it loads it from its cache, so a kernel whose
callee in another file changed ran the old callee. A folder keyed by every source file
makes any change compile afresh.
"""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from processing import kernel_cache

ROOT = Path(__file__).resolve().parents[1]


def _copy_package(tmp_path: Path) -> Path:
    dst = tmp_path / "processing"
    shutil.copytree(ROOT / "processing", dst, ignore=shutil.ignore_patterns("__pycache__"))
    return dst


def test_the_key_changes_with_any_source_file_and_only_with_them(tmp_path: Path) -> None:
    package = _copy_package(tmp_path)
    key = kernel_cache.source_key(package)
    assert key == kernel_cache.source_key(ROOT / "processing")
    assert len(key) == kernel_cache.KEY_LENGTH
    # compiled files and data beside the sources do not count
    (package / "solvers" / "__pycache__").mkdir()
    (package / "solvers" / "__pycache__" / "x.nbi").write_bytes(b"\0")
    assert kernel_cache.source_key(package) == key
    # a callee's file (the kind of change numba's own check misses)
    callee = package / "solvers" / "redblack.py"
    callee.write_text(callee.read_text() + "\n# changed\n")
    assert kernel_cache.source_key(package) != key


def test_a_process_compiles_into_its_versions_folder_and_children_keep_it(tmp_path: Path
                                                                          ) -> None:
    root = tmp_path / "cache"
    code = ("import os, numpy as np\n"
            "from processing.solvers import redblack\n"
            "redblack.compact_shape(4, 5)\n"
            "print(os.environ['NUMBA_CACHE_DIR'])\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(root), PYTHONPATH=str(ROOT))
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                           text=True, check=True, timeout=300).stdout.strip()
    folder = root / kernel_cache.source_key()
    assert Path(first) == folder
    assert any(folder.rglob("*.nbi")), "nothing compiled into the version's folder"
    # a child started with the parent's environment does not nest another folder
    env["NUMBA_CACHE_DIR"] = first
    second = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                            text=True, check=True, timeout=300).stdout.strip()
    assert Path(second) == folder
    assert sorted(p.name for p in root.iterdir()) == [folder.name]


def test_old_versions_beyond_the_kept_ones_are_removed(tmp_path: Path) -> None:
    root = tmp_path / "numba"
    root.mkdir()
    now = time.time()
    old = []
    for i in range(6):
        p = root / f"{i:016x}"
        p.mkdir()
        os.utime(p, (now - 100 * (i + 1), now - 100 * (i + 1)))
        old.append(p)
    other = root / "not-a-version"
    other.mkdir()
    current = root / ("f" * kernel_cache.KEY_LENGTH)
    current.mkdir()
    removed = kernel_cache.prune(root, current)
    kept = sorted(p.name for p in root.iterdir())
    # the current one and the KEEP_VERSIONS - 1 most recently used others stay
    assert sorted(p.name for p in removed) == [p.name for p in old[3:]]
    assert kept == sorted([current.name, other.name, *(p.name for p in old[:3])])


def test_a_version_folder_removed_by_another_process_meanwhile_is_passed_over(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two test processes start together on a fresh machine: one prunes a folder the
    other is looking at. The other still uses its version folder (a failure there would
    leave numba's own cache beside the sources, whose staleness the folders prevent)."""
    root = tmp_path / "numba"
    root.mkdir()
    gone = root / f"{1:016x}"
    gone.mkdir()
    real_stat = Path.stat
    looked = []

    def stat(self: Path, *args: object, **kwargs: object) -> os.stat_result:
        if self == gone:
            looked.append(self)
            if len(looked) > 1:  # seen as a folder, gone when its age is read
                shutil.rmtree(gone, ignore_errors=True)
                raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), str(gone))
        return real_stat(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(Path, "stat", stat)
    env = {"NUMBA_CACHE_DIR": str(root)}
    folder = kernel_cache.use_versioned_cache(env)
    assert folder == root / kernel_cache.source_key()
    assert env["NUMBA_CACHE_DIR"] == str(folder)
    assert len(looked) == 2 and not gone.exists()


def test_without_numba_cache_dir_the_users_cache_folder_is_the_root() -> None:
    assert kernel_cache.default_root({"XDG_CACHE_HOME": "/x"}) == Path("/x/ogiflow/numba")
    assert kernel_cache.default_root({"NUMBA_CACHE_DIR": "/var/cache/ogiflow/numba"}) == \
        Path("/var/cache/ogiflow/numba")
