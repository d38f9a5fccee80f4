"""Rig data at the file boundary: everything is SI inside, units are converted here.

Modules: :mod:`~ident.data.units` (unit systems and conversions),
:mod:`~ident.data.channels` (canonical channel names, corners, quantities),
:mod:`~ident.data.files` (atomic writes, TOML helpers), :mod:`~ident.data.runs`
(run tables: one CSV or Parquet file of signals, read and written through one checking
engine), :mod:`~ident.data.session` (rig-session folders: the manifest, the runs and
their shock library), :mod:`~ident.data.drive` (drive signals, generators and drive
files), :mod:`~ident.data.formats` (RPC III, MDF and TDMS files through channel
maps) and :mod:`~ident.data.tracklog` (track logs: what a car's data logger recorded on
track, from CSV, Parquet, MDF, TDMS or RPC III files).
"""
