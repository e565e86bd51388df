"""Parameter identification from pulse-discharge tests (seed 000 §2), without ROS.

``identify(test, ...)`` segments a pulse test into pulses and rests, takes OCV points from the
rests, fits the Saft RC model (eqs. 6-10) and the 2-RC Thevenin model (eqs. 17-18, linear then
nonlinear least squares) pulse by pulse, and returns a parameter set in the package's schema.
``soc_identify`` (``cli.py``) is the command around it.
"""

from .segment import IdentificationError, Pulse, segment_pulses

__all__ = ["IdentificationError", "Pulse", "segment_pulses"]
