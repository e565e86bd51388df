"""``soc_tune``: a battery file's filter tuning chosen on recordings, with cross-validation.

``objective.py`` scores one tuning on one recording; ``search.py`` holds the search space and
its candidates; ``crossval.py`` the folds and the choice; ``cli.py`` the command. ROS-free.
"""

from .crossval import CrossValidation, cross_validate, folds
from .objective import Score, score_recording
from .search import DEFAULT_SPACES, Dimension, candidates, parse_dimension

__all__ = [
    "DEFAULT_SPACES",
    "CrossValidation",
    "Dimension",
    "Score",
    "candidates",
    "cross_validate",
    "folds",
    "parse_dimension",
    "score_recording",
]
