"""Synthetic stereo OGI gas sequences with ground truth (paper Sec. 5.1).

- :mod:`~processing.synthetic.fluid`: 3D buoyant gas flow after Stam's Stable Fluids.
- :mod:`~processing.synthetic.render`: stereo ray casting with the radiometry of Eq. 1 and the
  left camera's ground truth (V*, 3D position, gas mask, column density).
- :mod:`~processing.synthetic.sequences`: presets (Table 2, field) and frame generation.
- :mod:`~processing.synthetic.storage`: the on-disk format ``ogiflow-synthetic/1``.
- :mod:`~processing.synthetic.reference`: Eq. 4's image quantities (u, v, d, d') from the
  ground truth, and the 3D reference of a raw-frame triplet.
"""

from processing.synthetic.storage import (
    FORMAT,
    SequenceFormatError,
    SyntheticFrame,
    iter_frames,
    list_sequences,
    read_frame,
    read_sequence_meta,
    write_sequence,
)

__all__ = [
    "FORMAT",
    "SequenceFormatError",
    "SyntheticFrame",
    "iter_frames",
    "list_sequences",
    "read_frame",
    "read_sequence_meta",
    "write_sequence",
]
