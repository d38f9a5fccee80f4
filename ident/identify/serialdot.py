"""Long dot products with numpy's multithreaded BLAS's bits, on one thread.

OpenBLAS (numpy's BLAS in its wheels) splits a dot product of more than
:data:`OPENBLAS_DOT_THRESHOLD` elements into one contiguous part per BLAS thread and adds
the parts' sums in order (``0 + s_0 + s_1 + ...``; its ``blas_level1_thread_with_return_value``,
part widths ``ceil(rest / threads_left)``). Each part is summed by the same single-thread
kernel as a short product. :func:`serial_dots` computes the same parts on one thread and adds
them in the same order, so the result is bit for bit the multithreaded one, without waking
the second thread for each product: a loop of many dot products of 10^4-10^5 samples (the
diagnosis' stiffening hinge, :func:`ident.identify.diagnose.diagnose_session`) spent more
CPU time in OpenBLAS's thread hand-over and spinning than in the sums (issue 40).

Where numpy's BLAS is not a pthreads OpenBLAS, or a check on a few test vectors finds the
split product different from numpy's own (another BLAS version or kernel), the products are
numpy's as they are (``float(a @ b)``): the same numbers as before either way.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os

import numpy as np

__all__ = ["OPENBLAS_DOT_THRESHOLD", "openblas_split_dot", "part_widths", "serial_dots"]

log = logging.getLogger(__name__)

#: OpenBLAS computes a dot product of at most this many elements on one thread
#: (``kernel/x86_64/ddot.c``: ``n <= 10000``).
OPENBLAS_DOT_THRESHOLD = 10000

#: Lengths of the self-check's test vectors: both sides of the threshold and a few parts'
#: widths, odd and even.
_CHECK_LENGTHS = (10000, 10001, 10002, 20011, 65536, 100003, 150001)


def openblas_split_dot(a, b, threads):
    """``a @ b`` as OpenBLAS computes it on `threads` threads, computed by numpy's BLAS as
    it is now (one thread: the caller limits it, see :func:`serial_dots`).

    Parameters
    ----------
    a, b : ndarray, shape (n,)
        Contiguous float64 vectors.
    threads : int
        The BLAS thread count whose split is reproduced.

    Returns
    -------
    float
    """
    n = a.shape[0]
    if threads <= 1 or n <= OPENBLAS_DOT_THRESHOLD:
        return float(a @ b)
    dot = 0.0
    start = 0
    for width in part_widths(n, threads):
        dot = dot + float(a[start:start + width] @ b[start:start + width])
        start += width
    return dot


def part_widths(n, threads):
    """The lengths of the parts OpenBLAS splits a level-1 product of `n` elements into on
    `threads` threads, in order (``blas_level1_thread_with_return_value``).

    Parameters
    ----------
    n : int
        Elements.
    threads : int
        BLAS threads (at least 1).

    Returns
    -------
    tuple of int
        Summing to `n`; each ``ceil(rest / threads_left)``.
    """
    widths = []
    rest = n
    while rest > 0:
        left = threads - len(widths)
        width = min((rest + left - 1) // left, rest)
        rest -= width
        widths.append(width)
    return tuple(widths)


@functools.lru_cache(maxsize=1)
def _numpy_blas():
    """numpy's own BLAS library's threadpoolctl controller, or None where it is not a
    pthreads OpenBLAS (or threadpoolctl cannot find it)."""
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - a dependency
        return None
    root = os.path.dirname(os.path.dirname(os.path.abspath(np.__file__)))
    numpy_dirs = tuple(os.path.join(root, d) for d in ("numpy.libs", "numpy", "numpy/.dylibs"))
    for lib in ThreadpoolController().select(user_api="blas").lib_controllers:
        if (lib.internal_api == "openblas" and getattr(lib, "threading_layer", "") == "pthreads"
                and os.path.abspath(lib.filepath).startswith(numpy_dirs)):
            return ThreadpoolController().select(filepath=lib.filepath)
    return None


@functools.lru_cache(maxsize=8)
def _split_matches(threads):
    """Whether :func:`openblas_split_dot` on one thread equals numpy's dot on `threads`
    threads, bit for bit, on test vectors (checked once per thread count and process)."""
    blas = _numpy_blas()
    rng = np.random.default_rng(40)
    pairs = [(rng.standard_normal(n) ** 3 * 10.0 ** rng.integers(-3, 4, n), rng.standard_normal(n))
             for n in _CHECK_LENGTHS]
    with blas.limit(limits=threads):
        want = [float(a @ b) for a, b in pairs]
    with blas.limit(limits=1):
        got = [openblas_split_dot(a, b, threads) for a, b in pairs]
    if got != want:
        log.debug("numpy's BLAS splits dot products otherwise: plain products kept")
    return got == want


@contextlib.contextmanager
def serial_dots():
    """A context in which numpy's BLAS runs on one thread; yields ``dot(a, b) -> float``,
    equal bit for bit to ``float(a @ b)`` on the BLAS threads numpy had on entering.

    Yields
    ------
    callable
        ``dot(a, b)`` for contiguous float64 vectors `a`, `b`; ``float(a @ b)`` unchanged
        where the split is not known to match (see the module's notes).

    Notes
    -----
    Other threads of the process that call BLAS meanwhile run on one thread too.
    """
    blas = _numpy_blas()
    threads = 1 if blas is None else int(blas.lib_controllers[0].num_threads)
    if threads <= 1 or not _split_matches(threads):
        yield _plain_dot
        return
    with blas.limit(limits=1):
        yield functools.partial(_dot_on, threads=threads)


def _plain_dot(a, b):
    return float(a @ b)


def _dot_on(a, b, *, threads):
    if a.dtype != np.float64 or b.dtype != np.float64:  # the check covered float64 only
        return float(a @ b)
    return openblas_split_dot(a, b, threads)
