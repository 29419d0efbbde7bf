#!/bin/sh
# The simulated sequences of the emission-rate acceptance, then the evaluation.
#
#   benchmarks/emission_sequences.sh OUT [PYTHON]
#
# writes OUT/<name>/ (ogiflow simulate, field preset: 30 Hz, 3 cm voxels, b = 0.3 m) and runs
# `ogiflow eval emission --data OUT --json OUT/emission.json --figures OUT/figures`.
# Releases 0.3-10 g/s, wind in and out of the image plane (Z = towards/away from the
# cameras), distances 3-15 m, with and without the camera non-idealities. The sequences
# whose wind has a Z component get a volume deep enough for the plume to leave through the
# side of the view rather than vanish through the volume's far or near face in mid-image
# (--volume-depth; r2_mostly_z_5m's plume, 72 deg out of the image plane, still reaches the
# far face inside the view at 9.1 m: `eval emission` marks it "v"). 135 frames (4.5 s,
# six correlation times of the release; 45 frames left a sequence's error to its
# realisation: r2_mostly_z_5m +14.5 or +20.2 % with spin-ups 0.4 s apart). About 30 min to
# simulate and 5 min to evaluate on one core.
set -eu
OUT=${1:?usage: $0 OUT [PYTHON]}
PY=${2:-.venv/bin/python}
FRAMES=${FRAMES:-135}
sim() {  # name release wind_x wind_y wind_z distance [camera effects...]
    name=$1 rate=$2 wx=$3 wy=$4 wz=$5 dist=$6
    shift 6
    "$PY" -m appliance simulate --preset field --name "$name" --out "$OUT" --force \
        --frames "$FRAMES" --release-rate "$rate" --wind "$wx" "$wy" "$wz" --distance "$dist" "$@"
}
sim r3_inplane_5m      3.0  1.5 0.0  0.0  5.5
sim r0.3_inplane_4m    0.3  1.0 0.0  0.0  4.0
sim r10_inplane_8m    10.0  2.5 0.0  0.0  8.0
sim r1_inplane_3m      1.0  1.0 0.0  0.0  3.0
sim r10_inplane_15m   10.0  2.0 0.0  0.0 15.0
sim r3_away_5m         3.0  1.2 0.0  1.2  5.5 --volume-depth 2.88
sim r3_towards_6m      3.0  1.0 0.0 -1.5  6.0 --volume-depth 2.88
sim r2_mostly_z_5m     2.0  0.6 0.0  1.8  5.5 --volume-depth 4.32
sim r3_away_5m_noisy   3.0  1.5 0.0  0.8  5.5 --volume-depth 2.88 \
    --noise 0.03 --jitter 0.2 --gain-mismatch 0.04
sim r1_left_10m_noisy  1.0 -1.5 0.0  0.0 10.0 --noise 0.03 --gain-mismatch 0.04
"$PY" -m appliance eval emission --data "$OUT" --json "$OUT/emission.json" \
    --figures "$OUT/figures"
