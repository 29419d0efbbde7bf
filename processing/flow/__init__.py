"""Stage 2: the left optical flow w_L (Sec. 4.2, Eq. 5), and OpenCV references."""
