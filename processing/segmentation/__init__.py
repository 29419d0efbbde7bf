"""Stage 5: the gas region by a two-region level set (Sec. 4.4, Eq. 9)."""
