"""``soc_tune --cache FILE``: the scores a search computed, kept on disk, so a stopped search
resumes where it stopped and a longer one (more ``--rounds``) starts from a shorter one's.

A search is deterministic (``compass.py``, ``search.py``): run again on the same inputs it asks
for the same tunings in the same order, so every score already in the cache is read instead of
computed, and the search goes on from the first tuning that is not.

The file is JSON lines. The first line says what the scores are of, the **context**: the
estimator, the convergence run's wrong start, and the SHA-256 of the battery file, of each
recording (in the order given) and of the package's Python source (a change to an estimator or
to the objective changes the scores). A cache made for another context is refused with one
line naming what differs; scores are never mixed across contexts. Every further line is one
tuning (its values, :func:`tuning_key`) and its score on each recording, appended and flushed
as soon as its last recording is scored. A line that does not parse (the last one, cut short
when a run was stopped mid-write) is skipped and counted (:attr:`ScoreCache.skipped`).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: The cache format; a file of another version is refused like another context.
CACHE_VERSION = 1

Key = tuple[tuple[str, float], ...]


def tuning_key(values: Mapping[str, float]) -> Key:
    """A tuning's identity: its labels and values to twelve significant digits (a move down
    and back up again, or a value read back from the cache, lands on the same tuning)."""
    return tuple(sorted((k, float(f"{v:.12g}")) for k, v in values.items()))


def _digest(root: Path, files: Sequence[Path]) -> str:
    """The SHA-256 of ``files`` in the order given, each after its path relative to ``root``
    (none for ``root`` itself: a single file is its bytes alone)."""
    h = hashlib.sha256()
    for f in files:
        if f != root:
            h.update(str(f.relative_to(root)).encode() + b"\0")
        with f.open("rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def _sha256(path: Path) -> str:
    """The digest of a file, or of a directory's files (a bag: its storage and metadata) in
    sorted order."""
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    return _digest(path, files)


def source_digest() -> str:
    """The SHA-256 of the package's Python source (``soc_estimator_ros/**/*.py``)."""
    root = Path(__file__).resolve().parents[1]
    return _digest(root, sorted(root.rglob("*.py")))


def context_of(
    estimator: str, params: Path, recordings: Sequence[str], wrong_start: float
) -> dict[str, Any]:
    """What a score depends on (module docstring)."""
    return {
        "version": CACHE_VERSION,
        "estimator": estimator,
        "wrong_start": float(wrong_start),
        "params_sha256": _sha256(params),
        "recordings_sha256": [_sha256(Path(p)) for p in recordings],
        "source_sha256": source_digest(),
    }


class ScoreCache:
    """Scores by tuning, read from and appended to ``path`` (module docstring)."""

    def __init__(self, path: Path, context: Mapping[str, Any]) -> None:
        """Open ``path`` for ``context``, creating it if it does not exist; a file made for
        another context raises ``ValueError`` (one line: which entries differ)."""
        self.path = path
        self.n_recordings = len(context["recordings_sha256"])
        self.rows: dict[Key, np.ndarray] = {}
        self.skipped = 0
        if not path.exists() or path.stat().st_size == 0:
            path.write_text(json.dumps({"context": dict(context)}) + "\n")
            return
        try:
            lines = path.read_text().splitlines()
            found = json.loads(lines[0])["context"]
        except (ValueError, KeyError, TypeError):  # UnicodeDecodeError too: a binary file
            raise ValueError(f"--cache {path}: not a soc_tune cache (first line)") from None
        differ = sorted(k for k in set(found) | set(context) if found.get(k) != context.get(k))
        if differ:
            raise ValueError(
                f"--cache {path}: made for other inputs ({', '.join(differ)} differ); "
                "give another path or remove it"
            )
        for line in lines[1:]:
            try:
                entry = json.loads(line)
                row = np.array(entry["scores"], dtype=float)
                key = tuning_key(entry["values"])
            except (ValueError, KeyError, TypeError):
                self.skipped += 1
                continue
            if row.shape != (self.n_recordings,):
                self.skipped += 1
                continue
            self.rows[key] = row

    def get(self, values: Mapping[str, float]) -> np.ndarray | None:
        """The tuning's scores on every recording, if cached."""
        return self.rows.get(tuning_key(values))

    def put(self, values: Mapping[str, float], row: Sequence[float]) -> None:
        """Keep the tuning's scores, appended to the file at once."""
        scores = [float(v) for v in row]
        if len(scores) != self.n_recordings:
            raise ValueError(f"{len(scores)} scores for {self.n_recordings} recordings")
        self.rows[tuning_key(values)] = np.array(scores)
        # json writes inf as Infinity and reads it back (a tuning that broke the filter).
        line = json.dumps({"values": dict(values), "scores": scores})
        with self.path.open("a") as fh:
            fh.write(line + "\n")
            fh.flush()

    def __len__(self) -> int:
        return len(self.rows)
