"""Evaluation (Sec. 5): metrics (Eq. 10), flow metrics, .flo files, decoupled baselines."""
