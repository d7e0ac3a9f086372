"""Exceptions a caller may want to catch. The command line turns any of them into a one-line message."""


class HarnessError(Exception):
    """Base class of every error this package raises on bad input."""


class ModelError(HarnessError):
    """The body model file is missing, malformed, or not a humanoid56-like model."""


class BodyError(ModelError, ValueError):
    """A call the body model cannot answer: a wrong array shape, a geom type it cannot sample, a bad count.
    Also a ``ValueError``, as these were before they became ``HarnessError``s."""


class UnknownNameError(ModelError, KeyError):
    """A joint or body name the model does not have (also a ``KeyError``); the message lists the valid ones."""

    def __str__(self) -> str:            # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class EngineError(HarnessError):
    """Input the engine cannot use: malformed observations, a database of the wrong shape, bad settings."""
