"""Exceptions a caller may want to catch. The command line turns any of them into a one-line message."""


class HarnessError(Exception):
    """Base class of every error this package raises on bad input."""


class ModelError(HarnessError):
    """The body model file is missing, malformed, or not a humanoid56-like model."""


class EngineError(HarnessError):
    """Input the engine cannot use: malformed observations, a database of the wrong shape, bad settings."""
