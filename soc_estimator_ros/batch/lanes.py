"""Recordings as lanes of the batch engine: ragged inputs, masks, and a run over them.

Lanes step in lock-step by sample index: step ``n`` hands every lane the ``n``-th sample of
its recording. Recordings of different lengths (or time bases) are padded: a lane whose
recording has ended, or that has no sample at a step (``active`` False), is frozen there
(its state untouched, status ``FROZEN``). A lane is a (recording, tuning) pair: several
lanes may read one recording (``lane_recording``), whose samples are stored once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..series import BatterySeries
from .ukf import BatchError, BatchT2rcUkf


@dataclass(frozen=True)
class LaneInputs:
    """Samples for K lanes: ``(R, N)`` arrays of R recordings padded to N samples, and the
    recording each lane reads.

    Attributes:
        t_s, current_a, voltage_v, temperature_c: the samples (temperature NaN: unknown).
        present: ``(R, N)``, True where recording r has a sample n (False in the padding, or
            where a recording skips a step).
        lane_recording: ``(K,)``, the recording of each lane.
    """

    t_s: np.ndarray
    current_a: np.ndarray
    voltage_v: np.ndarray
    temperature_c: np.ndarray
    present: np.ndarray
    lane_recording: np.ndarray

    def __post_init__(self) -> None:
        shape = self.t_s.shape
        arrays = (self.current_a, self.voltage_v, self.temperature_c, self.present)
        if len(shape) != 2 or any(a.shape != shape for a in arrays):
            raise BatchError(
                "lane inputs: t_s, current_a, voltage_v, temperature_c and present must be "
                f"(recordings, samples) arrays of one shape, got {[a.shape for a in arrays]}"
            )
        lanes = self.lane_recording
        if lanes.ndim != 1 or lanes.size == 0 or lanes.min() < 0 or lanes.max() >= shape[0]:
            raise BatchError(
                f"lane_recording: one recording index in [0, {shape[0]}) per lane, got {lanes}"
            )

    @property
    def n_lanes(self) -> int:
        return int(self.lane_recording.size)

    @property
    def n_steps(self) -> int:
        return int(self.t_s.shape[1])

    @classmethod
    def from_series(
        cls,
        series: Sequence[BatterySeries],
        lane_recording: Sequence[int] | np.ndarray | None = None,
        max_samples: int | None = None,
    ) -> LaneInputs:
        """Recordings padded to the longest (or its first ``max_samples``); by default one lane
        per recording."""
        if not series:
            raise BatchError("lane inputs: no recording")
        lengths = [len(s) if max_samples is None else min(len(s), max_samples) for s in series]
        n = max(lengths)
        shape = (len(series), n)
        t, cur, volt = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        temp = np.full(shape, np.nan)
        present = np.zeros(shape, dtype=bool)
        for r, (s, m) in enumerate(zip(series, lengths, strict=True)):
            t[r, :m], cur[r, :m], volt[r, :m] = s.t_s[:m], s.current_a[:m], s.voltage_v[:m]
            temp[r, :m] = s.temperature_c[:m]
            present[r, :m] = True
        lanes = np.arange(len(series)) if lane_recording is None else np.asarray(lane_recording)
        return cls(t, cur, volt, temp, present, lanes.astype(np.intp))


@dataclass(frozen=True)
class LaneRun:
    """Every lane after every step: ``(N, K)`` arrays (a frozen lane repeats its state;
    before a lane's first sample its SoC and variance are its initial ones)."""

    soc: np.ndarray
    soc_var: np.ndarray
    status: np.ndarray  # LaneStatus values
    voltage_pred_v: np.ndarray
    nis: np.ndarray


def run_lanes(engine: BatchT2rcUkf, inputs: LaneInputs, keep: bool = True) -> LaneRun | None:
    """Every step of ``inputs`` through ``engine`` (its lanes, in order); the outputs at every
    step when ``keep`` (``(N, K)`` each: mind the memory for many lanes and samples)."""
    k = inputs.n_lanes
    if engine.k != k:
        raise BatchError(f"the engine has {engine.k} lanes, the inputs {k}")
    rec = inputs.lane_recording
    n = inputs.n_steps
    out = None
    if keep:
        out = LaneRun(
            np.empty((n, k)),
            np.empty((n, k)),
            np.empty((n, k), dtype=np.int8),
            np.empty((n, k)),
            np.empty((n, k)),
        )
    one_each = rec.size == inputs.t_s.shape[0] and bool(np.all(rec == np.arange(rec.size)))
    cols = (inputs.t_s, inputs.current_a, inputs.voltage_v, inputs.temperature_c, inputs.present)
    for step in range(n):
        if one_each:
            t, cur, volt, temp, act = (a[:, step] for a in cols)
        else:
            t, cur, volt, temp, act = (a[rec, step] for a in cols)
        r = engine.step(t, cur, volt, temp, act)
        if out is not None:
            out.soc[step], out.soc_var[step], out.status[step] = r.soc, r.soc_var, r.status
            out.voltage_pred_v[step], out.nis[step] = r.voltage_pred_v, r.nis
    return out
