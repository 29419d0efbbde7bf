"""The disk quota of the recordings: the oldest closed files go first.

Only closed files of the appliance's own naming pattern (:func:`.files.closed_files`) are
ever deleted; the open file counts towards the total but stays.
"""

from __future__ import annotations

import logging
from pathlib import Path

from appliance.recording.files import closed_files

log = logging.getLogger("ogiflow.recorder")


def delete_oldest_over_quota(directory: Path, quota_gb: float, open_size: int) -> int:
    """Delete the oldest closed recordings until they and the open file fit ``quota_gb``.

    Parameters
    ----------
    directory : Path
        The recording directory.
    quota_gb : float
        The quota in GB (1e9 bytes).
    open_size : int
        Bytes of the open file (0 when none is open).

    Returns
    -------
    int
        How many files were deleted. A file that cannot be deleted stops the deletion (it
        is logged; the next rotation tries again).
    """
    limit = quota_gb * 1e9
    files = closed_files(directory)
    total = open_size + sum(p.stat().st_size for p in files)
    deleted = 0
    while total > limit and files:
        oldest = files.pop(0)
        size = oldest.stat().st_size
        try:
            oldest.unlink()
        except OSError as exc:
            log.error("recorder: quota: cannot delete %s: %s", oldest.name, exc)
            break
        total -= size
        deleted += 1
        log.warning("quota %.3g GB: deleted oldest recording %s (%.1f MB)", quota_gb,
                    oldest.name, size / 1e6)
    return deleted
