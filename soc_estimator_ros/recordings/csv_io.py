"""CSV recordings: ``time_s,current_a,voltage_v[,temperature_c][,soc_ref]`` (a cell tester's or
a laboratory's export; the current's sign is declared by the caller)."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from ..series import BatterySeries
from ..units import CurrentSign, core_current_from
from .bags import RecordingError


def read_csv(path: Path, sign: CurrentSign) -> BatterySeries:
    """A CSV with ``time_s,current_a,voltage_v`` and optional ``temperature_c``, ``soc_ref``.

    Other columns are ignored. A row whose ``time_s`` equals the previous row's is a cell
    tester's second record of a step boundary: the last record of that instant is kept and the
    count of dropped rows is in ``repeated_stamps``. A field missing from a short row (a logger
    stopped mid-line) reads as NaN, as an empty one does: the sample is then rejected where it
    is replayed, and counted. Time running backwards or not a number, and a file that is not
    text, are errors.
    """
    try:
        with path.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
    except UnicodeDecodeError as exc:
        raise RecordingError(
            path, f"not a text CSV file ({exc.reason} at byte {exc.start})"
        ) from exc
    if not rows:
        raise RecordingError(path, "no data rows")
    missing = {"time_s", "current_a", "voltage_v"} - set(rows[0])
    if missing:
        raise RecordingError(path, f"missing column(s) {', '.join(sorted(missing))}")

    def col(name: str) -> np.ndarray:
        if name not in rows[0]:
            return np.full(len(rows), math.nan)
        try:
            return np.array(
                [float(r[name]) if r[name] not in ("", None) else math.nan for r in rows]
            )
        except ValueError as exc:
            raise RecordingError(path, f"column {name}: {exc}") from exc

    t = col("time_s")
    if not math.isfinite(t[0]):
        raise RecordingError(path, f"time_s must be a finite number (row 2: {t[0]})")
    dt = np.diff(t)
    if not np.all(dt >= 0):  # a decrease, or a NaN or infinite time
        k = int(np.argmax(~(dt >= 0))) + 1
        raise RecordingError(
            path, f"time_s must not decrease (row {k + 2}: {t[k]} after {t[k - 1]})"
        )
    keep = np.concatenate([dt > 0, [True]])  # the last row of each instant

    def kept(name: str) -> np.ndarray:
        return col(name)[keep]

    current = np.array([core_current_from(float(i), sign) for i in kept("current_a")])
    soc_ref = kept("soc_ref")
    t = t[keep]
    return BatterySeries(
        t_s=t - t[0],
        stamp_ns=np.round(t * 1e9).astype(np.int64),
        current_a=current,
        voltage_v=kept("voltage_v"),
        temperature_c=kept("temperature_c"),
        soc_ref=None if np.all(np.isnan(soc_ref)) else soc_ref,
        repeated_stamps=int(np.count_nonzero(~keep)),
    )
