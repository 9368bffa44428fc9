"""Native libraries' own console output: silenced while they decode a user's file.

libpng, libtiff and OpenEXR print warnings of their own (``libpng error: ...``, ``Warning: Exception
raised reading pixel data``) on the process's stdout/stderr when a file is damaged, before our one-line
error that names the file. The decoders' results carry everything we report, so their lines are dropped
for the duration of the call, at the file-descriptor level (they write from C, below Python's streams).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def native_output_silenced() -> Iterator[None]:
    """File descriptors 1 and 2 point to the null device inside the block (Python's buffers are flushed
    first); where they cannot be redirected (closed descriptors), the block runs unchanged."""
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:
        yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)
