"""The planner's exception class.

Errors on a planning request (setups, objectives, crates, plans, what-if
files) are :class:`PlannerError`, a :class:`~ident.errors.ShockplanError`
and so a :class:`ValueError`, one sentence naming the file, the field and the fix.
"""

from ident.errors import ShockplanError

__all__ = ["PlannerError"]


class PlannerError(ShockplanError):
    """A setup, objective or planning request is malformed."""
