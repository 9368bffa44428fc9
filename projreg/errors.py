"""The one error type of projreg (re-exported as ``projreg.ProjregError``)."""


class ProjregError(Exception):
    """The one error the library raises for bad input; ``cli`` prints it as one line, exit 2."""
