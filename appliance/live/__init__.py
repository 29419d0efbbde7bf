"""The Rerun live view: viewer thread (``view``), viewer server process (``server``),
layout (``blueprint``) and display encodings (``colour``)."""

#: Most 3D velocity arrows drawn per result (``gas/velocity3d``). The workers subsample the
#: gas pixels to this many before sending a result (so the queue carries no more than is
#: shown); the live view caps anything else pushed to it at the same number.
MAX_ARROWS = 400
