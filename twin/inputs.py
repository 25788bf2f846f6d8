"""Reading an input file the user names: only a regular file, only up to a size cap.

A parameter, calibration or dataset path can name anything: ``/dev/zero`` (endless; reading it
grew memory without bound), a FIFO (blocks), a folder, or a file far larger than any the twin
writes. :func:`read_input` refuses each in one line naming the file, before reading it whole.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = ["InputFileError", "read_input", "CALIBRATION_MAX_BYTES", "DATASET_MAX_BYTES", "METADATA_MAX_BYTES",
           "PARAMS_MAX_BYTES"]

# Caps, each ~100x the largest such file the twin writes: a parameter file is ~5 kB, a
# calibration ~10 kB, a dataset's metadata.json ~20 kB, its measurements.csv ~1 kB a row (a
# full validation grid and a long dynamic recording stay well under 64 MB).
PARAMS_MAX_BYTES = 1 << 20
CALIBRATION_MAX_BYTES = 1 << 20
METADATA_MAX_BYTES = 4 << 20
DATASET_MAX_BYTES = 64 << 20


class InputFileError(ValueError):
    """An input that is not a regular file or is larger than its cap; the message names it."""


def read_input(path: str | Path, *, max_bytes: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``max_bytes`` of them.

    The file is opened without blocking (a FIFO does not hang the open) and checked on the open
    descriptor, so what is checked is what is read.

    Raises:
        FileNotFoundError, PermissionError: as :func:`open` does.
        InputFileError: not a regular file (a device, FIFO, socket or folder), or larger than
            ``max_bytes``.
    """
    path = Path(path)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            kind = ("a folder" if stat.S_ISDIR(info.st_mode) else "a device" if stat.S_ISCHR(info.st_mode)
                    or stat.S_ISBLK(info.st_mode) else "a FIFO" if stat.S_ISFIFO(info.st_mode) else "a socket")
            raise InputFileError(f"{path}: {kind}, not a regular file")
        if info.st_size > max_bytes:
            raise InputFileError(f"{path}: {info.st_size} bytes, more than the {max_bytes} such a file may have")
        with os.fdopen(fd, "rb", closefd=False) as fh:
            data = fh.read(max_bytes + 1)  # a file still growing is cut at the cap, not read on
        if len(data) > max_bytes:
            raise InputFileError(f"{path}: more than the {max_bytes} bytes such a file may have")
        return data
    finally:
        os.close(fd)
