"""Import PyBullet without its build banner on stdout (which would corrupt machine-readable output)."""

from __future__ import annotations

import os
import sys


def _quiet_import():
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 1)
            import pybullet
    finally:
        os.dup2(saved, 1)
        os.close(saved)
    return pybullet


p = _quiet_import()
