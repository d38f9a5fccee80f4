"""shockplan's data-to-model half: rig data, vehicle and shock models, simulation, identification.

The subpackages are the layers, bottom up; a module imports from its own layer and the
layers before it in this list:

:mod:`ident.data`
    Rig data at the file boundary: units, canonical channels, rig sessions and
    run tables, drives, and the real rig formats (RPC III, MDF, TDMS).
:mod:`ident.models`
    Models of the car's parts: the linear time-invariant types shared by physical
    and identified models (modal systems, the loop plant, discretization, balanced
    reduction), the physical 7-DOF full car, and shock models and shock libraries.
:mod:`ident.sim`
    The one closed-loop simulator (a linear plant with nonlinear shock
    feedback) with its compiled kernels, the RMS metrics, stiffness changes of a
    plant, and the virtual rig that writes rig sessions from a known car.
:mod:`ident.dyno`
    The shock dyno: raw dyno runs to dyno sheets, shock models fitted to a dyno
    sheet, and a virtual dyno (imports data and models; nothing in ident imports it).
:mod:`ident.identify`
    Identification: the multi-input FRF (the paper's Eqs. 18-28), its
    conditioning, rational fits, the identified model and its file, the pipeline
    that puts them together, the FIR reference, and the FRF plots.

One exception to the order: a rig session holds its shock library (and its bump-stop
library), so :mod:`ident.data.session` and :mod:`ident.data.formats` read and write it
through :mod:`ident.models.library` and :mod:`ident.models.bumpstops` (which, with the
models they hold, use only data's channels, units and files).
:mod:`ident.errors` holds the exception and warning classes every layer raises.
``ident`` never imports :mod:`planner`.
"""

__version__ = "0.1.0"
