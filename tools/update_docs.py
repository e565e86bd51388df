"""Regenerate the generated parts of docs/: the node's parameter table in docs/node.md.

    .venv/bin/python tools/update_docs.py          # rewrite docs/node.md in place
    .venv/bin/python tools/update_docs.py --check  # exit 1 if it is not current

test/unit/node/test_parameters.py runs the check, so the table never drifts from the
parameter spec (soc_estimator_ros/node/parameters.py).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from soc_estimator_ros.node.parameters import parameter_table

BEGIN, END = "<!-- parameters:begin -->", "<!-- parameters:end -->"


def with_table(text: str) -> str:
    """``text`` with the table between the markers replaced by the current one."""
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{parameter_table()}\n{END}{tail}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true")
    ap.add_argument(
        "--doc", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "node.md"
    )
    args = ap.parse_args()
    text = args.doc.read_text()
    new = with_table(text)
    if args.check:
        if new != text:
            print(
                f"{args.doc}: the parameter table is stale; run tools/update_docs.py",
                file=sys.stderr,
            )
            return 1
        return 0
    args.doc.write_text(new)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
