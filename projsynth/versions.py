"""projsynth's version and the dataset format versions it writes and reads (re-exported by the package)."""

__version__ = "0.2.0"

FORMAT_VERSION = 2  # 2: Fletcher-32 on every fixed-size dataset, CRC-32 of the variable-length ones
READABLE_FORMATS = (1, 2)  # what the readers accept (docs/format.md)
