"""The generator of the screening's straight-line band inverse.

:func:`planner.screen_kernels._band_inverse` is the Gauss-Jordan inverse of
``I - Hv diag(D)`` (4x4, partial pivoting) written out for one band: the 16
entries held in scalars, the pivot search and the row and column interchanges
written as selects, so that a loop over bands around it has no branches and no
scratch memory and LLVM vectorizes it over bands. Its operations are those of
:func:`planner.screen_kernels._loop_inverse`, in the same order (the screening's
fixed point amplifies any round-off change, so the two must agree bit for bit).

Writing 300 such lines by hand invites a slip; this module writes them.
:func:`band_inverse_source` returns the function's source text exactly as it
stands in ``planner/screen_kernels.py`` between the markers :data:`BEGIN` and
:data:`END`; ``tests/test_screen.py`` regenerates it and compares. After a
change here, rewrite the block with::

    python -m planner.screen_codegen --write

Examples
--------
>>> src = band_inverse_source()
>>> src.splitlines()[1]
'def _band_inverse(h, d0, d1, d2, d3):'
>>> sum(line.strip().startswith("dd = _recip(") for line in src.splitlines())
4
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["BEGIN", "END", "KERNEL_PATH", "band_inverse_source", "committed_source", "main"]

#: The kernel module holding the generated block.
KERNEL_PATH = Path(__file__).with_name("screen_kernels.py")
#: The comment line before the generated block.
BEGIN = ("# BEGIN GENERATED CODE by planner.screen_codegen "
         "(python -m planner.screen_codegen --write)")
#: The comment line after the generated block.
END = "# END GENERATED CODE by planner.screen_codegen"

_N = 4  # the loop has four shocks
_DOCSTRING = '''\
    """K = (I - Hv diag(D))^-1 of band k, straight-line (Gauss-Jordan, partial pivoting).

    Generated code (:mod:`planner.screen_codegen`): the same operations, in the same order, as
    :func:`_loop_inverse` (pivots by ``|z|^2``, row interchanges, in-place elimination,
    column interchanges undone in reverse), with the 16 entries held in scalars and the
    row and column interchanges written as selects, so that a loop over bands around it
    has no branches and no scratch memory and LLVM vectorizes it over bands. h: the 16
    entries of ``-Hv`` (row-major), loaded by :func:`_screen_one` (scalars only: an array
    passed to an inlined function costs reference counting, which stops vectorization).
    """'''


def _a(i, j):
    """The scalar holding entry (i, j)."""
    return f"a{i}{j}"


def _select_swap(lines, s, x, y):
    """Swap the scalars x and y where s holds, as selects (no branch)."""
    lines += [f"t = {x}", f"{x} = {y} if {s} else {x}", f"{y} = t if {s} else {y}"]


def band_inverse_source():
    """The source text of ``_band_inverse``, decorator to return, as committed.

    Returns
    -------
    str
        Lines ending in newlines, indented by four spaces in the body.

    Notes
    -----
    For each column ``c``: the pivot ``p_c``, the first row ``i >= c`` of the
    largest ``|a_ic|^2`` (a strictly larger one replaces it, in row order);
    the rows ``c`` and ``p_c`` interchanged (one select swap per candidate row,
    only the chosen one taking effect); row ``c`` scaled by ``1 / a_cc``
    (:func:`planner.screen_kernels._recip`, the division as numba computes it)
    with ``a_cc`` set to 1 first (in place: the identity's column); every other
    row ``i`` reduced, ``a_ic`` set to 0 first. Then the row interchanges undone
    as column interchanges of the inverse, the last column first.
    """
    n = _N
    body = []
    for i in range(n):
        body += [f"{_a(i, j)} = h[{n * i + j}] * d{j}" for j in range(n)]
        body.append(f"{_a(i, i)} = complex({_a(i, i)}.real + 1.0, {_a(i, i)}.imag + 0.0)")
    for c in range(n):
        if c < n - 1:
            body.append(f"# column {c}")
            body.append(f"big = {_a(c, c)}.real * {_a(c, c)}.real + "
                        f"{_a(c, c)}.imag * {_a(c, c)}.imag")
            body.append(f"p{c} = {c}")
            for i in range(c + 1, n):
                body += [f"m2 = {_a(i, c)}.real * {_a(i, c)}.real + "
                         f"{_a(i, c)}.imag * {_a(i, c)}.imag",
                         "up = m2 > big", "big = m2 if up else big", f"p{c} = {i} if up else p{c}"]
            for i in range(c + 1, n):
                body.append(f"s = p{c} == {i}")
                for j in range(n):
                    _select_swap(body, "s", _a(c, j), _a(i, j))
        else:
            body.append(f"# column {c} (its pivot is the last row: nothing to compare)")
        body += [f"dd = _recip({_a(c, c)})", f"{_a(c, c)} = 1.0 + 0j"]
        body += [f"{_a(c, j)} = {_a(c, j)} * dd" for j in range(n)]
        for i in range(n):
            if i != c:
                body += [f"f = {_a(i, c)}", f"{_a(i, c)} = 0j"]
                body += [f"{_a(i, j)} = {_a(i, j)} - f * {_a(c, j)}" for j in range(n)]
    body.append("# the row interchanges become column interchanges of the inverse, undone in "
                "reverse")
    for c in range(n - 2, -1, -1):
        for p in range(c + 1, n):
            body.append(f"s = p{c} == {p}")
            for i in range(n):
                _select_swap(body, "s", _a(i, c), _a(i, p))
    body.append("return (" + ", ".join(_a(i, j) for i in range(n) for j in range(n)) + ")")
    args = ", ".join(["h"] + [f"d{j}" for j in range(n)])
    lines = ['@nb.njit(cache=True, error_model="numpy", inline="always")',
             f"def _band_inverse({args}):", _DOCSTRING]
    lines += ["    " + line for line in body]
    return "\n".join(lines) + "\n"


def committed_source(text=None):
    """The generated block as committed in the kernel module, between the markers.

    Parameters
    ----------
    text : str, optional
        The module's source; default read from :data:`KERNEL_PATH`.

    Returns
    -------
    str

    Raises
    ------
    ValueError
        If the markers are missing or out of order.
    """
    if text is None:
        text = KERNEL_PATH.read_text(encoding="utf-8")
    head, sep, rest = text.partition(BEGIN + "\n")
    block, sep2, _ = rest.partition(END + "\n")
    if not sep or not sep2:
        raise ValueError(f"{KERNEL_PATH}: the generated block's markers ({BEGIN!r} ... {END!r}) "
                         "are missing; restore them around _band_inverse")
    return block


def main(argv=None):
    """Print the generated source, or (``--write``) replace the kernel module's block."""
    parser = argparse.ArgumentParser(prog="python -m planner.screen_codegen",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true",
                        help=f"rewrite the generated block in {KERNEL_PATH.name}")
    args = parser.parse_args(argv)
    src = band_inverse_source()
    if not args.write:
        sys.stdout.write(src)
        return 0
    text = KERNEL_PATH.read_text(encoding="utf-8")
    old = committed_source(text)
    KERNEL_PATH.write_text(text.replace(BEGIN + "\n" + old + END + "\n",
                                        BEGIN + "\n" + src + END + "\n", 1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
