"""The generator of the screening's straight-line band inverse.

:func:`planner.screen_kernels._band_inverse` is the Gauss-Jordan inverse of
``I - Hv diag(D)`` (4x4, partial pivoting) written out for one band: the 16
entries held in scalars, the pivot search and the row and column interchanges
written as selects, so that a loop over bands around it has no branches and no
scratch memory and LLVM vectorizes it over bands. Its operations are those of
:func:`planner.screen_kernels._loop_inverse`, in the same order (the screening's
fixed point amplifies any round-off change, so the two must agree bit for bit).

Writing 300 such lines by hand invites a slip; this module writes them, the metrics'
pass ``_metrics_of`` of the same module (:func:`metric_pass_source`: each metric's band
power written out over the 48 features, between :data:`METRICS_BEGIN` and
:data:`METRICS_END`), and also the third-element kernel's fused band loops
(:func:`third_band_source`: ``_band_power`` and ``_band_features`` of
:mod:`planner.screen_third_kernels`, between
:data:`THIRD_BEGIN` and :data:`THIRD_END`; ``tests/test_screen_third.py`` compares).
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

__all__ = ["BEGIN", "END", "KERNEL_PATH", "METRICS_BEGIN", "METRICS_END", "THIRD_BEGIN",
           "THIRD_END", "THIRD_KERNEL_PATH", "band_inverse_source", "committed_source", "main",
           "metric_pass_source", "third_band_source"]

#: The kernel module holding the generated block.
KERNEL_PATH = Path(__file__).with_name("screen_kernels.py")
#: The comment line before the generated block.
BEGIN = ("# BEGIN GENERATED CODE by planner.screen_codegen "
         "(python -m planner.screen_codegen --write)")
#: The comment line after the generated block.
END = "# END GENERATED CODE by planner.screen_codegen"
#: The markers around the metrics' pass (:func:`metric_pass_source`) in the same module.
METRICS_BEGIN = ("# BEGIN GENERATED METRICS by planner.screen_codegen "
                 "(python -m planner.screen_codegen --write)")
METRICS_END = "# END GENERATED METRICS by planner.screen_codegen"
#: Features of a band and metrics per pass of :func:`metric_pass_source` (the kernel's
#: ``_NFEAT`` and ``_MQ``): three accumulators of 48 terms each is what LLVM's loop
#: vectorizer still takes on (four are too many memory accesses for its dependence analysis).
_NFEAT = 48
_MQ = 3
_METRICS_DOC = '''\
    """The metrics of G setups from their band features V[g] (:func:`_screen_one`).

    Each metric's band power is d0 plus a fixed linear form of the band's features (F, from
    the operands), summed over bands, in the reference's order per setup: ``pw = d0[k]``,
    ``pw += F[k, i] v_i`` for i in order, then the band powers added in band order. Laid
    out by :func:`metric_blocks` (Fq, d0q: ``_MQ`` metrics per group, bands in blocks of
    ``_BK`` as V), each group's band powers are straight-line code over the 48 features in
    a loop over the bands of a block that LLVM vectorizes over bands (the ``_MQ`` sums held
    in registers, no fastmath); a block's coefficients (18 kB) are shared by the G setups
    while in cache. PW (G, n_blocks * _MQ * _BK) is scratch; nf the bands in use.
    Generated code (:mod:`planner.screen_codegen`)."""'''

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



# ---------------------------------------------------------------- third elements' band loops

#: The third-element kernel module holding the second generated block.
THIRD_KERNEL_PATH = Path(__file__).with_name("screen_third_kernels.py")
#: The comment lines around the third-element kernel's generated block.
THIRD_BEGIN = "# BEGIN GENERATED CODE by planner.screen_codegen (third elements)"
THIRD_END = "# END GENERATED CODE by planner.screen_codegen (third elements)"

_POWER_DOC = '''\
    """One iteration's band work, fused and written out: per band ``Delta`` (the corners'
    damping on the diagonal, the 4 element slots by their outer products: heave front, heave
    rear, roll front, roll rear, each within its axle, so Delta is block diagonal and the
    cross-axle terms are left out), ``A = I - H_vs Delta``, ``K = A^-1`` (:func:`_inv4`) and
    ``V = K P K^H`` (its real diagonal and the real parts of its upper triangle) into V
    (``10 _BK`` per block of bands: entry q of band ``blk _BK + j`` at ``(10 blk + q) _BK +
    j``). Straight-line code on scalars in a loop over the bands of a block (no branches, no
    scratch memory, the operands at constant offsets in two arrays: LLVM vectorizes it over
    bands, as the plain kernel's band loop); ceq, keq: the dampers' ``c_eq`` and springs'
    ``k_eq`` over the 8 rows (the 4 corners, the 4 element slots: zero rows where no
    element); rinv: the setup's roll-offs ``1 / (1 + j w tau)`` per row in blocks
    (:func:`_screen_third_one`). Generated code (:mod:`planner.screen_codegen`)."""'''
_FEATURES_DOC = '''\
    """The final pass's band work, fused and written out: per band ``Delta``, ``K`` as in
    :func:`_band_power`, then ``E = Delta K`` and the 48 features of ``E`` and ``R = E PB
    E^H`` (the diagonal of R, the real and imaginary parts of its upper triangle and of E,
    as :func:`planner.screen_kernels.metric_form` orders them) into V (``_NFEAT _BK`` per
    block: feature i of band ``blk _BK + j`` at ``(_NFEAT blk + i) _BK + j``). Straight-line,
    vectorized over bands as :func:`_band_power`. Generated code
    (:mod:`planner.screen_codegen`)."""'''
#: The element slots of each axle's block (heave, roll): front 0, 2; rear 1, 3.
_AXLE_SLOTS = {0: (0, 2), 1: (1, 3)}


def _emit(lines, text, indent):
    """Append ``indent`` levels of ``text``, an assignment's sum wrapped under 100 columns."""
    pre = "    " * indent
    if len(pre + text) <= 99 or " = " not in text:
        lines.append(pre + text)
        return
    lhs, rhs = text.split(" = ", 1)
    terms = rhs.split(" + ")
    cur = pre + lhs + " = (" + terms[0]
    for t in terms[1:]:
        if len(cur) + len(t) + 3 > 98:
            lines.append(cur)
            cur = pre + "    + " + t
        else:
            cur += " + " + t
    lines.append(cur + ")")


def _third_head(name, doc, out_rows):
    """The common part: the loads, ``Delta``, ``A = I - H Delta`` and ``K = A^-1``."""
    L = ['@nb.njit(cache=True, error_model="numpy")',
         f"def {name}(bd, ceq, keq, rinv, V):", doc]
    L.append("    ops, outer, cbar = bd.blocks, bd.outer, bd.cbar")
    L.append("    nblk = (bd.w.size + _BK - 1) // _BK")
    for r in range(8):
        L.append(f"    c{r} = ceq[{r}]")
        L.append(f"    q{r} = keq[{r}]")
    for c in range(4):
        L.append(f"    cb{c} = cbar[{c}]")
    for e in range(4):
        for i in range(16):
            if (i // 4) // 2 == (i % 4) // 2 == e % 2:
                L.append(f"    o{e}_{i} = outer[{4 + e}, {i}]")
    L += ["    for blk in range(nblk):", "        ob = blk * _NOPS * _BK",
          "        rb = blk * 16 * _BK", f"        vb = blk * {out_rows} * _BK",
          "        for j in range(_BK):", "            o = ob + j", "            r = rb + j",
          "            jk = ops[o + 64 * _BK]"]
    for c in range(4):
        _emit(L, f"g{c} = c{c} * complex(rinv[r + {c} * _BK], rinv[r + {8 + c} * _BK]) - cb{c}"
              f" + complex(0.0, q{c} * jk)", 3)
    for e in range(4):
        _emit(L, f"e{e} = c{4 + e} * complex(rinv[r + {4 + e} * _BK], rinv[r + {12 + e} * _BK])"
              f" + complex(0.0, q{4 + e} * jk)", 3)
    for i in range(4):
        for j in range(4):
            if i // 2 != j // 2:
                continue  # the elements act within an axle: Delta is block diagonal
            terms = " + ".join(f"o{e}_{4 * i + j} * e{e}" for e in _AXLE_SLOTS[i // 2])
            _emit(L, f"d{i}{j} = " + (f"g{i} + " if i == j else "") + terms, 3)
    for i in range(16):
        _emit(L, f"h{i // 4}{i % 4} = complex(ops[o + {i} * _BK], ops[o + {16 + i} * _BK])", 3)
    for i in range(4):
        for j in range(4):
            s = " + ".join(f"h{i}{m} * d{m}{j}" for m in range(4) if m // 2 == j // 2)
            _emit(L, f"a{i}{j} = " + (f"1.0 - ({s})" if i == j else f"-({s})"), 3)
    L.append("            (" + ", ".join(f"k{i}{j}" for i in range(4) for j in range(4))
             + ") = \\")
    L.append("                _inv4(" + ", ".join(f"a{i}{j}" for i in range(2) for j in range(4))
             + ",")
    L.append("                      " + ", ".join(f"a{i}{j}" for i in range(2, 4)
                                                  for j in range(4)) + ")")
    return L


def _dot_re(t, x, a, b):
    """``Re sum_c t_ac conj(x_bc)`` written out."""
    return " + ".join(f"{t}{a}{c}.real * {x}{b}{c}.real + {t}{a}{c}.imag * {x}{b}{c}.imag"
                      for c in range(4))


def third_band_source():
    """The third-element kernel's fused band loops, ``_band_power`` and ``_band_features``
    (:mod:`planner.screen_third_kernels`), as they stand between :data:`THIRD_BEGIN` and
    :data:`THIRD_END`.

    Returns
    -------
    str
    """
    L = _third_head("_band_power", _POWER_DOC, 10)
    for i in range(16):
        _emit(L, f"p{i // 4}{i % 4} = complex(ops[o + {32 + i} * _BK], ops[o + {48 + i} * _BK])",
              3)
    for a in range(4):
        for b in range(4):
            _emit(L, f"t{a}{b} = " + " + ".join(f"k{a}{c} * p{c}{b}" for c in range(4)), 3)
    for a in range(4):
        _emit(L, f"V[vb + j + {a} * _BK] = " + _dot_re("t", "k", a, a), 3)
    q = 4
    for a in range(3):
        for b in range(a + 1, 4):
            _emit(L, f"V[vb + j + {q} * _BK] = " + _dot_re("t", "k", a, b), 3)
            q += 1
    L += ["", ""]
    L += _third_head("_band_features", _FEATURES_DOC, "_NFEAT")
    for i in range(16):
        _emit(L, f"pb{i // 4}{i % 4} = complex(ops[o + {65 + i} * _BK], "
              f"ops[o + {81 + i} * _BK])", 3)
    for a in range(4):
        for b in range(4):
            _emit(L, f"x{a}{b} = " + " + ".join(f"d{a}{c} * k{c}{b}" for c in range(4)
                                                 if c // 2 == a // 2), 3)
    for a in range(4):
        for b in range(4):
            _emit(L, f"t{a}{b} = " + " + ".join(f"x{a}{c} * pb{c}{b}" for c in range(4)), 3)
    for a in range(4):
        _emit(L, f"V[vb + j + {a} * _BK] = " + _dot_re("t", "x", a, a), 3)
    q = 0
    for a in range(3):
        for b in range(a + 1, 4):
            _emit(L, f"z{q} = " + " + ".join(f"t{a}{c} * np.conj(x{b}{c})" for c in range(4)), 3)
            q += 1
    for q in range(6):
        L.append(f"            V[vb + j + {4 + q} * _BK] = z{q}.real")
        L.append(f"            V[vb + j + {10 + q} * _BK] = z{q}.imag")
    for a in range(4):
        for b in range(4):
            L.append(f"            V[vb + j + {16 + 4 * a + b} * _BK] = x{a}{b}.real")
            L.append(f"            V[vb + j + {32 + 4 * a + b} * _BK] = x{a}{b}.imag")
    return "\n".join(L) + "\n"


def metric_pass_source():
    """The metrics' pass ``_metrics_of`` of :mod:`planner.screen_kernels` as it stands between
    :data:`METRICS_BEGIN` and :data:`METRICS_END`: per group of ``_MQ`` metrics and block of
    bands, each metric's band power written out over the 48 features."""
    L = ['@nb.njit(cache=True, error_model="numpy")',
         "def _metrics_of(Fq, d0q, V, G, out, PW, nf):", _METRICS_DOC,
         "    nblk = PW.shape[1] // (_MQ * _BK)",
         "    p = out.shape[1]",
         "    for q in range(Fq.shape[0]):",
         "        fq = Fq[q]",
         "        dq = d0q[q]",
         "        for blk in range(nblk):",
         "            fb = blk * _NFEAT * _MQ * _BK",
         "            vb = blk * _NFEAT * _BK",
         "            db = blk * _MQ * _BK",
         "            for g in range(G):",
         "                v = V[g]",
         "                pw = PW[g]",
         "                for j in range(_BK):  # vectorized over bands"]
    for r in range(_MQ):
        L.append(f"                    a{r} = dq[db + {r} * _BK + j]" if r else
                 "                    a0 = dq[db + j]")
    L += ["                    x = fb + j", "                    y = vb + j"]
    for i in range(_NFEAT):
        L.append("                    " + (f"u = v[y + {i} * _BK]" if i else "u = v[y]"))
        for r in range(_MQ):
            c = _MQ * i + r
            L.append(f"                    a{r} += fq[x + {c} * _BK] * u" if c else
                     "                    a0 += fq[x] * u")
    for r in range(_MQ):
        L.append(f"                    pw[db + {r} * _BK + j] = a{r}" if r else
                 "                    pw[db + j] = a0")
    L += ["        for g in range(G):  # each metric's band powers added in band order",
          "            pw = PW[g]"]
    L += [f"            t{r} = 0.0" for r in range(_MQ)]
    L += ["            for k in range(nf):",
          "                x = (k // _BK) * _MQ * _BK + k % _BK"]
    L += [f"                t{r} += pw[x + {r} * _BK]" if r else "                t0 += pw[x]"
          for r in range(_MQ)]
    L.append("            o = _MQ * q")
    for r in range(_MQ):
        if r:
            L.append(f"            if o + {r} < p:")
            L.append(f"                out[g, o + {r}] = math.sqrt(max(t{r}, 0.0))")
        else:
            L.append("            out[g, o] = math.sqrt(max(t0, 0.0))")
    return "\n".join(L) + "\n"


def committed_source(text=None, *, third=False, metrics=False):
    """The generated block as committed in the kernel module, between the markers.

    Parameters
    ----------
    text : str, optional
        The module's source; default read from :data:`KERNEL_PATH` (with `third`:
        :data:`THIRD_KERNEL_PATH`).
    third : bool
        The third-element kernel's block (:data:`THIRD_BEGIN` ... :data:`THIRD_END`).
    metrics : bool
        The metrics' pass (:data:`METRICS_BEGIN` ... :data:`METRICS_END`, in
        :data:`KERNEL_PATH`).

    Returns
    -------
    str

    Raises
    ------
    ValueError
        If the markers are missing or out of order.
    """
    path, begin, end = ((THIRD_KERNEL_PATH, THIRD_BEGIN, THIRD_END) if third else
                        (KERNEL_PATH, METRICS_BEGIN, METRICS_END) if metrics else
                        (KERNEL_PATH, BEGIN, END))
    if text is None:
        text = path.read_text(encoding="utf-8")
    head, sep, rest = text.partition(begin + "\n")
    block, sep2, _ = rest.partition(end + "\n")
    if not sep or not sep2:
        raise ValueError(f"{path}: the generated block's markers ({begin!r} ... {end!r}) "
                         "are missing; restore them around the generated functions")
    return block


def main(argv=None):
    """Print the generated source, or (``--write``) replace the kernel module's block."""
    parser = argparse.ArgumentParser(prog="python -m planner.screen_codegen",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true",
                        help=f"rewrite the generated blocks in {KERNEL_PATH.name} and "
                        f"{THIRD_KERNEL_PATH.name}")
    args = parser.parse_args(argv)
    blocks = ((KERNEL_PATH, BEGIN, END, band_inverse_source(), {}),
              (KERNEL_PATH, METRICS_BEGIN, METRICS_END, metric_pass_source(), {"metrics": True}),
              (THIRD_KERNEL_PATH, THIRD_BEGIN, THIRD_END, third_band_source(), {"third": True}))
    if not args.write:
        sys.stdout.write("\n\n".join(b[3] for b in blocks))
        return 0
    for path, begin, end, src, which in blocks:
        text = path.read_text(encoding="utf-8")
        old = committed_source(text, **which)
        path.write_text(text.replace(begin + "\n" + old + end + "\n",
                                     begin + "\n" + src + end + "\n", 1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
