"""shockplan planner: from vehicle models to shock-setup decisions."""

__version__ = "0.1.0"
