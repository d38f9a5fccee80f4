"""Plain text for a terminal: the right-aligned tables the results' summaries print."""

from __future__ import annotations

__all__ = ["format_table"]


def format_table(rows, headers):
    """A table as text: a header line, a rule, one line per row, columns right-aligned.

    Parameters
    ----------
    rows : sequence of sequence
        The cells (any objects; ``str`` of each is printed), one sequence per row.
    headers : sequence of str

    Returns
    -------
    str
        Lines joined by newlines; columns two spaces apart, each as wide as its widest cell.

    Examples
    --------
    >>> print(format_table([(1, "a"), (10, "bc")], ["n", "name"]))
     n  name
    --  ----
     1     a
    10    bc
    """
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(headers)]
    line = "  ".join(str(h).rjust(w) for h, w in zip(headers, widths))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(str(c).rjust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join(out)
