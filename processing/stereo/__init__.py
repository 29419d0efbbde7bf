"""Stage 3: disparity d_L and its change d'_L jointly (Sec. 4.3, Eq. 6), SGM start."""
