"""icarus-vision: vision-based autonomous drone racing.

Importing the package registers the Gymnasium environment ``IcarusRace-v0``.
"""

__version__ = "0.1.0"

from icarus_vision.sim.registration import register as _register

_register()
