"""Radix-selected medians and quantiles (processing.preprocess.order_statistics) equal
numpy's to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from processing.preprocess.order_statistics import mad_spread, median, quantile


def _samples(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    if kind == "normal":
        return rng.standard_normal(n).astype(np.float32)
    if kind == "ties":  # few distinct values, zeros among them
        return rng.integers(-3, 4, n).astype(np.float32)
    if kind == "tiny":  # both signs, one exponent range apart
        return (rng.random(n) * 1e-3 * rng.choice([-1.0, 1.0], n)).astype(np.float32)
    values = np.abs(rng.standard_normal(n) * 10).astype(np.float32)
    values[: n // 3] = -0.0  # signed zeros sort with the zeros
    return values


@pytest.mark.parametrize("kind", ["normal", "ties", "tiny", "zeros"])
def test_median_and_quantiles_equal_numpys(kind: str) -> None:
    rng = np.random.default_rng(len(kind))
    for n in (1, 2, 3, 10, 11, 64, 999, 1000, 4097):
        v = _samples(kind, n, rng)
        assert median(v) == float(np.median(v))
        for q in (0.0, 0.25, 0.5, 0.9, 0.999, 1.0, float(rng.random())):
            assert quantile(v, q) == float(np.quantile(v, q)), (n, q)


def test_robust_spread_equals_numpys_and_takes_strided_views() -> None:
    rng = np.random.default_rng(7)
    for shape in ((240, 320), (7, 9), (1, 1)):
        img = (0.5 + 0.01 * rng.standard_normal(shape)).astype(np.float32)
        sub = img[::2, ::2]
        want = 1.4826 * float(np.median(np.abs(sub - np.median(sub))))
        assert mad_spread(img) == want
    img = rng.random((40, 60)).astype(np.float32)[5:-5, ::3]  # not contiguous
    sub = img[::2, ::2]
    assert mad_spread(img) == 1.4826 * float(np.median(np.abs(sub - np.median(sub))))
    assert median(img) == float(np.median(img))


def test_other_dtypes_and_empty_samples_are_refused() -> None:
    with pytest.raises(ValueError, match="float32"):
        median(np.ones(5))
    with pytest.raises(ValueError, match="float32"):
        quantile(np.ones(0, np.float32), 0.5)
    with pytest.raises(ValueError, match="2-D"):
        mad_spread(np.ones(5, np.float32))
