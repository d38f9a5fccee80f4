"""Rig data at the file boundary: everything is SI inside, units are converted here.

Modules: :mod:`~ident.data.units` (unit systems and conversions),
:mod:`~ident.data.channels` (canonical channel names, corners, quantities),
:mod:`~ident.data.files` (atomic writes, TOML helpers), :mod:`~ident.data.session`
(rig-session folders and run tables), :mod:`~ident.data.drive` (drive signals,
generators and drive files) and :mod:`~ident.data.formats` (RPC III, MDF and
TDMS files through channel maps).
"""
