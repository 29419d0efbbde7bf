"""Everything below a folder a user names, through symlinked folders.

Archives are often assembled from links (``data/site-a -> /mnt/archive/2026/site-a``).
``Path.rglob`` does not descend into a symlinked folder on Python 3.11 and 3.12, so a
sequence, a footage set or a recording reached that way was silently not found. This walk
follows such links and enters every real folder once, so a link back to a parent cannot
loop.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path


def walk(root: Path) -> Iterator[Path]:
    """Every folder and file below ``root`` (not ``root`` itself), symlinked folders
    followed, each real folder entered once; folders and files in name order, a folder
    before what it holds."""
    seen = {os.path.realpath(root)}

    def below(folder: Path) -> Iterator[Path]:
        try:
            entries = sorted(folder.iterdir())
        except OSError:  # unreadable, or vanished while walking
            return
        for entry in entries:
            yield entry
            if entry.is_dir():
                real = os.path.realpath(entry)
                if real not in seen:
                    seen.add(real)
                    yield from below(entry)

    yield from below(root)
