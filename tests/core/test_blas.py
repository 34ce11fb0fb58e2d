"""core.blas: blas_threads' limit on any thread; serial_matmul, a matrix product with the same bits whatever BLAS's
thread count."""

import threading

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from nlipscalib.core.blas import SERIAL_GEMM_MNK, serial_matmul


def _on(threads: int, fn):
    with threadpool_limits(limits=threads, user_api="blas"):
        return fn()


@pytest.mark.parametrize(
    "m, k, n",
    [
        (218, 1200, 24),  # a gather's block: 1,200 patches, 8 LEDs
        (98, 300, 9),  # blocks of 97 rows: the last would be a single row
        (5, 30_000, 36),  # a row of the whole k does not fit: k cut too
        (1, 2000, 24),  # one receiver
    ],
)
def test_serial_products_have_the_same_bits_on_one_and_two_blas_threads(m, k, n):
    rng = np.random.default_rng(m + k + n)
    a, b = rng.random((m, k), dtype=np.float32), rng.random((k, n), dtype=np.float32)
    one = _on(1, lambda: serial_matmul(a, b))
    assert one.shape == (m, n) and one.dtype == np.float32
    np.testing.assert_array_equal(_on(2, lambda: serial_matmul(a, b)), one)
    np.testing.assert_allclose(one, a.astype(np.float64) @ b.astype(np.float64), rtol=1e-5)


def test_a_serial_products_pieces_are_each_within_the_single_thread_size(monkeypatch):
    """Every product it asks NumPy for has at most SERIAL_GEMM_MNK multiply-adds and two rows or more."""
    sizes = []
    plain = np.matmul

    def spy(x, y, *args, **kwargs):
        sizes.append((x.shape[0], x.shape[1], y.shape[1]))
        return plain(x, y, *args, **kwargs)

    monkeypatch.setattr(np, "matmul", spy)
    rng = np.random.default_rng(0)
    for m, k, n in [(218, 1200, 24), (98, 300, 9), (5, 30_000, 36)]:
        sizes.clear()
        serial_matmul(rng.random((m, k)), rng.random((k, n)))
        assert sizes and all(r >= 2 and r * kk * nn <= SERIAL_GEMM_MNK for r, kk, nn in sizes), sizes


@pytest.mark.parametrize("m, k, n", [(0, 5, 24), (7, 0, 24), (7, 5, 0), (0, 0, 0)])
def test_a_serial_product_with_an_empty_side_is_numpys(m, k, n):
    """An empty factor (a flat pad's gather has no surface pairs: Q3's flat-pad press failed on a division by zero)
    gives NumPy's product: zeros where nothing is summed, an empty array where a side is empty."""
    a, b = np.ones((m, k), np.float32), np.ones((k, n), np.float32)
    out = serial_matmul(a, b)
    assert out.shape == (m, n) and out.dtype == np.float32
    np.testing.assert_array_equal(out, a @ b)


def test_a_block_on_any_thread_gets_its_count_while_another_thread_holds_a_blas_limit():
    """threadpoolctl (3.8) ignores a limit set on a thread other than the one holding its control (here the main
    thread's ``with``): the way Q1's calibration task, run on the Dask test's thread, got 2 BLAS threads inside its
    ``blas_threads(1)``. Blocks overlapping on two threads keep the count until the last ends, then the counts from
    before the first are back."""
    from nlipscalib.core.blas import blas_setting, blas_threads

    seen: dict = {}
    first_in, first_out = threading.Event(), threading.Event()

    def first():
        with blas_threads(1):
            first_in.set()
            seen["first"] = blas_setting()
            first_out.wait(60)

    def second():
        first_in.wait(60)
        with blas_threads(1):
            first_out.set()
            thread.join(60)  # the first block has ended meanwhile
            seen["second, the first ended"] = blas_setting()

    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_setting()
        thread = threading.Thread(target=first)
        other = threading.Thread(target=second)
        thread.start()
        other.start()
        other.join(60)
        after = blas_setting()
    assert set(before) == {2}, before
    assert seen == {"first": (1,) * len(before), "second, the first ended": (1,) * len(before)}, seen
    assert after == before
