"""projreg's version (re-exported by the package)."""

__version__ = "0.2.0"
