"""Tests of ident.identify.serialdot: long dot products with the multithreaded BLAS's bits."""
import numpy as np
import pytest

from ident.identify.serialdot import (OPENBLAS_DOT_THRESHOLD, openblas_split_dot, part_widths,
                                      serial_dots)

#: Lengths around the threshold and the parts' widths, odd and even, as the diagnosis meets.
LENGTHS = (100, OPENBLAS_DOT_THRESHOLD, OPENBLAS_DOT_THRESHOLD + 1, 20001, 40000, 79999)


def test_part_widths_known_answers():
    assert part_widths(10001, 2) == (5001, 5000)
    assert part_widths(10007, 3) == (3336, 3336, 3335)
    assert part_widths(10, 4) == (3, 3, 2, 2)
    assert part_widths(5, 1) == (5,)


def test_short_products_are_numpys():
    rng = np.random.default_rng(1)
    a, b = rng.standard_normal((2, 500))
    assert openblas_split_dot(a, b, 2) == float(a @ b)


def test_split_product_adds_the_parts_in_order():
    rng = np.random.default_rng(2)
    a, b = rng.standard_normal((2, 30001)) ** 3
    w = part_widths(30001, 2)
    want = (0.0 + float(a[:w[0]] @ b[:w[0]])) + float(a[w[0]:] @ b[w[0]:])
    assert openblas_split_dot(a, b, 2) == want


@pytest.mark.parametrize("n", LENGTHS)
def test_serial_dots_equal_numpys_products_bit_for_bit(n):
    # the products as numpy computes them on its BLAS threads, then inside the one-thread
    # context: the same bits (a different BLAS falls back to numpy's own product)
    rng = np.random.default_rng(n)
    a = rng.standard_normal(n) ** 3 * 10.0 ** rng.integers(-3, 4, n)
    b = rng.standard_normal(n)
    want = (float(a @ b), float(a @ a))
    with serial_dots() as dot:
        got = (dot(a, b), dot(a, a))
    assert got == want


def test_serial_dots_take_float32_as_numpy_does():
    rng = np.random.default_rng(3)
    a = rng.standard_normal(30000).astype(np.float32)
    want = float(a @ a)
    with serial_dots() as dot:
        assert dot(a, a) == want
