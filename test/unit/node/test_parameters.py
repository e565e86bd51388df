"""The node's parameter table (node/parameters.py): parsing, --help, and docs/node.md kept
current (ROS-free: the table is read without a ROS context)."""

from __future__ import annotations

import subprocess
import sys

import pytest
from conftest import REPO_ROOT

from soc_estimator_ros.node.parameters import (
    PARAMETERS,
    NodeConfigError,
    parameter_table,
    parse_initial_soc,
    usage,
)


def test_docs_node_md_holds_the_current_table() -> None:
    out = subprocess.run(
        [sys.executable, str(REPO_ROOT / "tools" / "update_docs.py"), "--check"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr


def test_every_parameter_is_in_the_table_and_the_help() -> None:
    table, text = parameter_table(), usage()
    for spec in PARAMETERS:
        assert f"`{spec.name}`" in table and spec.name in text


@pytest.mark.parametrize(
    ("value", "parsed"),
    [("0.8", 0.8), (0.8, 0.8), (1, 1.0), ("OCV", "ocv"), ("resume", "resume")],
)
def test_initial_soc_parses(value, parsed) -> None:
    assert parse_initial_soc(value) == parsed


@pytest.mark.parametrize("value", ["full", "1.5", True, -0.1])
def test_initial_soc_refuses(value) -> None:
    with pytest.raises(NodeConfigError, match="initial_soc"):
        parse_initial_soc(value)
