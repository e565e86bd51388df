"""The data a recording holds and the data an estimator produces over it (plain numpy, no ROS).

:class:`BatterySeries` is one recording (a bag or a CSV), aligned, in stamp order;
:class:`EstimateSeries` is an estimator's output over a recording, one row per input sample;
:class:`RuntimeSeries` the runtime monitor's predictions over it, one row per input sample too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np


class SampleSeries(Protocol):
    """Aligned arrays of a run's samples: what ``evaluation.run_estimator`` and
    :meth:`EstimateSeries.over` read (:class:`BatterySeries` fits)."""

    @property
    def t_s(self) -> np.ndarray: ...
    @property
    def current_a(self) -> np.ndarray: ...
    @property
    def voltage_v(self) -> np.ndarray: ...
    @property
    def temperature_c(self) -> np.ndarray: ...


@dataclass(frozen=True)
class BatterySeries:
    """Samples of one recording, aligned, in stamp order.

    Attributes:
        t_s: seconds since the first sample.
        stamp_ns: absolute header stamps (ns).
        current_a: current in A, core convention (positive while discharging).
        voltage_v: pack voltage in V.
        temperature_c: temperature in degC (NaN where the bridge sent none).
        soc_ref: reference SoC (fraction) at each sample, or None without a reference topic.
        design_capacity_ah: the bridge's design capacity (NaN if not sent).
        technology: ``power_supply_technology`` of the first sample.
        reference_capacity_ah: capacity behind the reference SoC, or None.
        serial_number: the pack's ``serial_number`` in the first sample ("" if none).
        repeated_stamps: rows dropped on reading because they repeated the previous row's
            time (a CSV from a cell tester logs a record at both sides of a step boundary).
        cell_voltage_v: the cells' voltages (V), ``(samples, cells)`` in series order (NaN
            where a sample has none), or None when the bridge sent no ``cell_voltage``.
        cell_soc_ref: the reference SoC of every cell, the same shape, or None.
    """

    t_s: np.ndarray
    stamp_ns: np.ndarray
    current_a: np.ndarray
    voltage_v: np.ndarray
    temperature_c: np.ndarray
    soc_ref: np.ndarray | None = None
    design_capacity_ah: float = math.nan
    technology: int = 0
    reference_capacity_ah: float | None = None
    serial_number: str = ""
    repeated_stamps: int = 0
    cell_voltage_v: np.ndarray | None = None
    cell_soc_ref: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t_s)

    def window(self, lo: int, hi: int | None = None) -> BatterySeries:
        """Samples ``lo`` to ``hi`` (exclusive) as a recording of their own (time from 0)."""
        sl = slice(lo, hi)
        return replace(
            self,
            t_s=self.t_s[sl] - self.t_s[lo],
            stamp_ns=self.stamp_ns[sl],
            current_a=self.current_a[sl],
            voltage_v=self.voltage_v[sl],
            temperature_c=self.temperature_c[sl],
            soc_ref=None if self.soc_ref is None else self.soc_ref[sl],
            cell_voltage_v=None if self.cell_voltage_v is None else self.cell_voltage_v[sl],
            cell_soc_ref=None if self.cell_soc_ref is None else self.cell_soc_ref[sl],
        )


@dataclass(frozen=True)
class EstimateSeries:
    """An estimator's outputs over a run, one row per input sample."""

    estimator: str
    t_s: np.ndarray
    soc: np.ndarray
    soc_std: np.ndarray
    voltage_v: np.ndarray
    voltage_pred_v: np.ndarray
    current_a: np.ndarray
    nis: np.ndarray
    status: tuple[str, ...]
    innovation_v: np.ndarray
    x: np.ndarray  # (n, dim_x): the state after each sample
    p: np.ndarray  # (n, dim_x, dim_x): its covariance
    state_names: tuple[str, ...]
    #: With cell voltages (``cells/``): every cell's SoC and std, (n, cells); ``soc`` and
    #: ``soc_std`` are then the usable discharge SoC and ``soc_lumped``, ``soc_lumped_std``
    #: the pack's estimate.
    cell_soc: np.ndarray | None = None
    cell_soc_std: np.ndarray | None = None
    soc_lumped: np.ndarray | None = None
    soc_lumped_std: np.ndarray | None = None
    #: The estimate vector's ``cell.*`` values per row (``cells.cell_field_names`` order).
    cell_fields: np.ndarray | None = None

    @classmethod
    def over(cls, run: SampleSeries, **outputs: Any) -> EstimateSeries:
        """The estimator's ``outputs`` (every other field) over ``run``, whose time, voltage
        and current the series carries beside them."""
        return cls(
            t_s=np.asarray(run.t_s, dtype=float),
            voltage_v=np.asarray(run.voltage_v, dtype=float),
            current_a=np.asarray(run.current_a, dtype=float),
            **outputs,
        )


#: The runtime predictions a replay keeps per sample (``soc_replay --output`` columns first).
RUNTIME_COLUMNS = (
    "time_to_empty_s",
    "time_to_empty_std_s",
    "time_to_full_s",
    "max_discharge_current_10s_a",
    "max_discharge_current_60s_a",
    "max_charge_current_10s_a",
    "level",
)
#: The health monitor's learned values per row (``health/``; NaN with health off).
HEALTH_COLUMNS = ("capacity_ah", "r0_factor")


@dataclass(frozen=True)
class RuntimeSeries:
    """The runtime monitor over a run, one row per input sample: the latest prediction
    (``runtime/monitor.py``; NaN before the first), and the FULL status at each sample.

    Attributes:
        values: one array per name of :data:`RUNTIME_COLUMNS` and :data:`HEALTH_COLUMNS`.
        full: FULL held after the sample (``power_supply_status``).
        soc_empty: the SoC the time to empty runs to (``limits.soc_min``).
    """

    values: dict[str, np.ndarray]
    full: np.ndarray
    soc_empty: float

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[name]
