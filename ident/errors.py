"""Exception and warning classes of :mod:`ident`, the bases of :mod:`planner`'s too.

Every error raised on user input subclasses :class:`ValueError` or
:class:`TypeError` so that callers who do not know the project still catch it,
and a project class so that callers who do can catch a whole family.
"""

__all__ = [
    "ShockplanError",
    "SessionError",
    "TrackLogError",
    "ShockModelError",
    "BumpStopError",
    "VehicleError",
    "DriveError",
    "IdentificationError",
    "ModelFileError",
    "DynoError",
    "AeroModelError",
    "ShockplanWarning",
    "LowCoherenceWarning",
    "FitWarning",
]


class ShockplanError(ValueError):
    """Base class of the project's value errors (bad input with a fix hint)."""


class SessionError(ShockplanError):
    """A rig session folder, manifest or run file is malformed."""


class TrackLogError(SessionError):
    """A track log (a car's data-logger file) or its channel map cannot be read as one.

    A :class:`SessionError` too: a track log is read by the same engines as the rig's runs.
    """


class ShockModelError(ShockplanError):
    """A shock model or shock library is malformed."""


class BumpStopError(ShockplanError):
    """A bump stop, a bump-stop library or a packer is malformed."""


class VehicleError(ShockplanError):
    """A vehicle parameter file is malformed."""


class DriveError(ShockplanError):
    """A drive file or drive specification is malformed."""


class IdentificationError(ShockplanError):
    """The experiment or the data cannot identify the requested model."""


class ModelFileError(ShockplanError):
    """A saved model file is corrupt or of an unsupported version."""


class DynoError(ShockplanError):
    """A raw dyno file, its dyno map or a dyno sheet cannot be read or turned into points."""


class AeroModelError(ShockplanError):
    """An aero model (downforce and balance by speed or ride height) or its file is malformed,
    or its loads are asked for with bad speeds or ride heights."""


class ShockplanWarning(UserWarning):
    """Base class of the project's warnings (a result is computed but doubtful)."""


class LowCoherenceWarning(ShockplanWarning):
    """An estimate rests on frequencies with poor coherence or no excitation."""


class FitWarning(ShockplanWarning):
    """A parametric fit did not converge or had to be modified (e.g. poles reflected)."""
