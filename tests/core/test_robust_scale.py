import numpy as np
import pytest

from nlipscalib.core.robust_scale import mad_scale


def test_mad_scale_known_answers():
    assert mad_scale([1.0, 2.0, 3.0, 4.0, 100.0]) == pytest.approx(1.4826)  # |x - 3| has median 1; 100 is ignored
    assert mad_scale(np.zeros((0, 3))) == 0.0
    assert mad_scale(np.full((4, 5), 7.0)) == 0.0
    sample = np.random.default_rng(0).normal(5.0, 2.0, 200_000)
    assert mad_scale(sample) == pytest.approx(2.0, rel=0.01)  # a normal sample's standard deviation


def test_mad_scale_center_and_dtype_keep_the_callers_arithmetic():
    """The copies it replaced took the medians in float32 (contact noise, the live change rule) and reused a
    median they already had: the same calls give the same bits."""
    sample = np.random.default_rng(1).gamma(2.0, 1.0, 10_001).astype(np.float32)
    median = float(np.median(sample))
    assert mad_scale(sample, center=median, dtype=np.float32) == 1.4826 * float(np.median(np.abs(sample - median)))
    m32 = np.median(sample)
    assert mad_scale(sample, dtype=np.float32) == 1.4826 * float(np.median(np.abs(sample - m32)))
    r = sample.astype(np.float64)
    assert mad_scale(sample) == 1.4826 * float(np.median(np.abs(r - np.median(r))))
    assert mad_scale(sample[:-1]) == mad_scale(sample[:-1], center=float(np.median(r[:-1])))
