"""ROS-free tracking of one battery's SoC over a sample stream: the input gate
(``gate``), the pairing of separate current and voltage readings (``pairing``), the state file
(``persistence``) and the :class:`Tracker` that ties them to an estimator (``tracker``).
The node and ``soc_replay`` both feed their samples through a :class:`Tracker`."""

from __future__ import annotations

from .gate import REJECTIONS, GateConfig, InputGate, Verdict
from .pairing import PairedSample, ScalarPairer
from .persistence import ResumeDecision, SavedState, StateFileError, resume_health
from .tracker import Event, Level, Sample, StepResult, Tracker, TrackerConfig

__all__ = [
    "REJECTIONS",
    "Event",
    "GateConfig",
    "InputGate",
    "Level",
    "PairedSample",
    "ResumeDecision",
    "Sample",
    "SavedState",
    "ScalarPairer",
    "StateFileError",
    "StepResult",
    "Tracker",
    "TrackerConfig",
    "Verdict",
    "resume_health",
]
