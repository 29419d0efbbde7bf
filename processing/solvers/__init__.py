"""Shared by stages 2-3: coarse-to-fine warping, lagged diffusivity, red-black SOR."""
