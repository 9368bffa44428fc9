"""projreg: the SSJM registration network: train, benchmark and apply it to projector-camera pairs."""

__version__ = "0.2.0"


class ProjregError(Exception):
    """The one error the library raises for bad input; ``cli`` prints it as one line, exit 2."""
