"""The shock dyno: raw dyno runs, shock models fitted to dyno sheets, a virtual dyno.

Modules: :mod:`~ident.dyno.raw` (raw dyno time series to dyno-sheet rows, ``shockplan
dyno import``), :mod:`~ident.dyno.sheet_fit` (shock models fitted to a dyno sheet's peak
force against peak velocity) and :mod:`~ident.dyno.virtual` (a virtual shock dyno: a
known shock driven by a stroke program, the truth of the raw import). The adjustable
shocks built from dyno sheets are a shock model of the library
(:mod:`ident.models.adjustable`). The package sits above ``ident.models`` (it imports
``ident.data`` and ``ident.models``; nothing in ``ident`` imports it) and re-exports
nothing, so importing one module loads only that one.
"""
