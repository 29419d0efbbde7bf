"""The recorder of a run: files a crash left finished first, then the metadata and the layout.

Every file of a run carries the configuration, the calibration, the processing parameters
and the emission set-up (so replay computes as the run did); ``recording.split`` chooses
the retention layout (raw frames apart, event clips kept) over one stream of files.
"""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path
from typing import Any

from appliance.config import Config
from appliance.recording.clips import ClipKeeper
from appliance.recording.metadata import file_metadata, processing_metadata
from appliance.recording.recorder import Recorder
from appliance.recording.recovery import recover_unfinished
from appliance.recording.split import SplitRecorder
from appliance.runtime.emission_setup import EmissionSetup
from processing.chain import ChainParameters, StereoGeometry

log = logging.getLogger("ogiflow")


def start_recorder(cfg: Config, geometry: StereoGeometry | None, params: ChainParameters,
                   emission: EmissionSetup | None,
                   stack: contextlib.ExitStack) -> tuple[Any, ClipKeeper | None]:
    """Recover unfinished files, then start the recorder of ``cfg.recording``.

    Returns the started recorder and, with ``recording.split``, the event clips' keeper,
    whose close is registered on ``stack`` (the caller registers the recorder's close after
    it, so the keeper closes last and links the recorder's last raw file too).
    """
    rc = cfg.recording
    rc.dir.mkdir(parents=True, exist_ok=True)
    for folder in (rc.dir, rc.dir / "raw", rc.dir / "data"):
        for rep in recover_unfinished(folder):
            log.warning("recovered %s after a crash", rep)
    cal_text = Path(cfg.calibration).read_text() if cfg.calibration is not None else None
    metadata = file_metadata(cfg, cal_text)
    if geometry is not None:
        metadata.update(processing_metadata(geometry, params))
    if emission is not None:  # replay computes the rate as this run did
        metadata["emission"] = {"json": emission.to_json()}
    if not rc.split:
        return Recorder(rc, metadata).start(), None
    clips = ClipKeeper(rc.dir / "raw", rc.dir / "events", pre_s=rc.pre_trigger_s,
                       post_s=rc.post_trigger_s, quota_gb=rc.events_quota_gb)
    stack.callback(clips.close)  # after the recorder: its last raw file too
    return SplitRecorder(rc, metadata).start(), clips
