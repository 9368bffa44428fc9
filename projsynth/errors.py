"""The one error type of projsynth (re-exported as ``projsynth.ProjsynthError``)."""


class ProjsynthError(Exception):
    """The one error the library raises for bad input; ``cli`` prints it as one line, exit 2."""
