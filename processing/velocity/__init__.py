"""Stage 4: 3D velocity V (Eq. 4), the virtual gas surface, quality (Eqs. 7-8)."""
