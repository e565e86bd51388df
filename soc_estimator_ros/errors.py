"""The package's errors: one base class, so a caller can catch every expected failure at once.

Each subsystem raises its own subclass (a battery file, a recording, a state file, a node
parameter, a replay input); each message is one line that names the file or parameter and says
what is wrong, which the command-line tools print as ``<tool>: error: <message>``.
"""

from __future__ import annotations


class SocEstimatorError(Exception):
    """Base of every error this package raises on bad input or configuration."""
