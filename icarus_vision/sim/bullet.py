"""Import PyBullet without its build banner (printed by the C module on import)."""

from __future__ import annotations

import ctypes
import os
import sys


def _quiet_import():
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    try:
        with open(os.devnull, "w") as devnull:
            for fd in saved:
                os.dup2(devnull.fileno(), fd)
            import pybullet

            ctypes.CDLL(None).fflush(None)  # push buffered C output to devnull before restoring
    finally:
        for fd, dup in saved.items():
            os.dup2(dup, fd)
            os.close(dup)
    return pybullet


p = _quiet_import()
