"""Stage 1 (Sec. 4.1): correction, rectification, differential images (Eq. 2), denoising."""
