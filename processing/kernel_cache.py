"""Where numba keeps the compiled kernels: one folder per version of this package's code.

numba's on-disk cache (``cache=True``) checks only the file that defines a kernel: a kernel
that calls into another module (the solvers' skeleton calling the SOR sweeps, the data
terms, the layout helpers) keeps the callee compiled into its cache entry, and after that
other file changes, the cached caller still runs the old callee (numba's documentation of
``cache=True`` says so). After a ``git pull`` of an editable install, or a copy of new sources over
old ones, the chain would compute with a mix of old and new code and say nothing.

:func:`use_versioned_cache`, called when :mod:`processing` is imported and before any
kernel is defined, points numba's cache at ``<root>/<key>``: ``key`` is a hash of every
source file of this package, ``root`` the ``NUMBA_CACHE_DIR`` the environment sets (the
service sets ``/var/cache/ogiflow/numba``), else ``$XDG_CACHE_HOME/ogiflow/numba``
(``~/.cache/ogiflow/numba``). Code that differs in any file compiles afresh into its own
folder; the oldest folders beyond :data:`KEEP_VERSIONS` are removed.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

#: Cache folders of other code versions kept under the root (the current one included).
KEEP_VERSIONS = 4

#: Length of the folder name (hex digits of the source hash).
KEY_LENGTH = 16

_PACKAGE = Path(__file__).resolve().parent


def source_key(package: Path = _PACKAGE) -> str:
    """Hash of every ``.py`` file under ``package``: relative paths and contents, sorted.

    Parameters
    ----------
    package : Path
        The package's folder.

    Returns
    -------
    str
        :data:`KEY_LENGTH` hex digits.
    """
    h = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        h.update(path.relative_to(package).as_posix().encode())
        h.update(b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:KEY_LENGTH]


def default_root(environ: os._Environ[str] | dict[str, str] = os.environ) -> Path:
    """The folder that holds one cache folder per code version."""
    given = environ.get("NUMBA_CACHE_DIR", "")
    if given:
        return Path(given)
    base = environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ogiflow" / "numba"


def prune(root: Path, current: Path, keep: int = KEEP_VERSIONS) -> list[Path]:
    """Remove the least recently used version folders under ``root`` beyond ``keep``
    (``current`` never); returns what was removed. Only folders named like a key are
    touched."""
    used: list[tuple[float, Path]] = []
    for p in root.iterdir():
        if p.is_dir() and len(p.name) == KEY_LENGTH and p != current \
                and all(c in "0123456789abcdef" for c in p.name):
            try:
                used.append((p.stat().st_mtime, p))
            except FileNotFoundError:  # another process (a test runner's) pruned it
                continue
    used.sort(reverse=True)
    removed = [p for _, p in used[max(keep - 1, 0):]]
    for p in removed:
        shutil.rmtree(p, ignore_errors=True)
    return removed


def use_versioned_cache(environ: os._Environ[str] | dict[str, str] = os.environ) -> Path:
    """Point numba's cache at this code version's folder; returns it.

    Sets ``NUMBA_CACHE_DIR`` in ``environ`` (child processes inherit it and keep it: a
    root that already ends in this version's key is used as it is) and numba's config.
    A root that cannot be created leaves numba's own choice in place.
    """
    import numba

    key = source_key()
    root = default_root(environ)
    folder = root if root.name == key else root / key
    try:
        folder.mkdir(parents=True, exist_ok=True)
        os.utime(folder)
        prune(folder.parent, folder)
    except OSError:
        return Path(numba.config.CACHE_DIR or "")
    environ["NUMBA_CACHE_DIR"] = str(folder)
    numba.config.CACHE_DIR = str(folder)
    return folder
