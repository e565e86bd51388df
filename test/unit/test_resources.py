"""resources.py: the one chemistry -> bundled file map, found in the checkout (the installed
cases are in test/packaging/)."""

from __future__ import annotations

import pytest
from conftest import REPO_ROOT

from soc_estimator_ros.errors import SocEstimatorError
from soc_estimator_ros.params import CHEMISTRIES, load_battery_params
from soc_estimator_ros.resources import (
    BUNDLED_FILES,
    ResourceError,
    bundled_file,
    config_dir,
    default_battery_file,
)


def test_every_chemistry_has_a_bundled_file_of_that_chemistry() -> None:
    assert set(BUNDLED_FILES) == set(CHEMISTRIES)
    for chemistry in CHEMISTRIES:
        assert load_battery_params(bundled_file(chemistry)).chemistry == chemistry


def test_the_checkout_is_found_first() -> None:
    assert config_dir() == REPO_ROOT / "config"
    assert default_battery_file() == REPO_ROOT / "config" / "sla_12v5ah.yaml"


def test_an_unknown_chemistry_is_one_clear_error() -> None:
    with pytest.raises(ResourceError, match="nimh") as info:
        bundled_file("nimh")
    assert isinstance(info.value, SocEstimatorError)
