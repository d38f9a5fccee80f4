"""shockplan's data-to-model half: rig data, vehicle and shock models, simulation, identification.

The subpackages are the layers, each importing only those above it in this list:

:mod:`ident.data`
    Rig data at the file boundary: units, canonical channels, rig sessions and
    run tables, drives, and the real rig formats (RPC III, MDF, TDMS).
:mod:`ident.models`
    Models of the car's parts: the physical 7-DOF full car, shock models and
    shock libraries, and the linear time-invariant types shared by physical
    and identified models.
:mod:`ident.sim`
    The one closed-loop simulator (a linear plant with nonlinear shock
    feedback) with its compiled kernels, the RMS metrics, and the virtual rig
    that writes rig sessions from a known car.
:mod:`ident.identify`
    Identification: the multi-input FRF (the paper's Eqs. 18-28), its
    conditioning, rational fits, the identified model and its file, the FIR
    reference, and the FRF plots.

:mod:`ident.errors` holds the exception and warning classes every layer raises.
``ident`` never imports :mod:`planner`.
"""

__version__ = "0.1.0"
