"""What a replay writes: the CSV of estimates, a bag like the node's output, plots, progress."""

from __future__ import annotations

import csv
import math
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..evaluation import remaining_time_s
from ..messages import (
    BATTERY_STATE,
    FLOAT64_ARRAY,
    TECHNOLOGY_BY_CHEMISTRY,
    bridge_state,
    estimate_row,
    estimate_state,
    layout_label,
)
from ..params import BatteryParams
from ..recordings import (
    REFERENCE_TOPIC,
    STATE_TOPIC,
    battery_state_message,
    float64_array_message,
    write_bag,
)
from ..series import HEALTH_COLUMNS, BatterySeries, EstimateSeries
from .run import ReplayError, ReplayResult

#: The error panel's axis never reaches past this (points); estimators beyond are marked.
ERROR_AXIS_MAX_PCT = 20.0
#: ... nor stays inside this (points), so a good run still shows its scale.
ERROR_AXIS_MIN_PCT = 2.5


class ProgressBar:
    """A text progress bar on stderr: ``soc_replay: NAME [#####.....]  50 %``."""

    def __init__(self, label: str, width: int = 30, prog: str = "soc_replay") -> None:
        self.label, self.width, self.prog = label, width, prog

    def __call__(self, done: int, total: int) -> None:
        filled = self.width * done // max(total, 1)
        bar = "#" * filled + "." * (self.width - filled)
        end = "\n" if done >= total else ""
        sys.stderr.write(
            f"\r{self.prog}: {self.label} [{bar}] {100 * done // max(total, 1):3d} %{end}"
        )
        sys.stderr.flush()


def write_output_bag(
    path: Path, series: BatterySeries, battery: BatteryParams, results: list[ReplayResult]
) -> None:
    """The input and the estimates as a new bag (MCAP), on the node's topics and types.

    ``/battery/state`` (with the cells' voltages when the input has them) and
    ``/battery/soc_reference`` (when the input has one) as recorded;
    ``/battery/soc`` as the node publishes it (``messages.estimate_state``) and
    ``/battery/soc_estimate``; with several estimators, each one's topics under
    ``/<estimator>/``. Rows before an estimator's first accepted sample are not written.
    """
    if path.exists():
        raise ReplayError(f"--output-bag {path}: exists; give a new directory")
    tech = TECHNOLOGY_BY_CHEMISTRY.get(battery.chemistry, 0)
    n = len(series)
    stamps = [int(s) for s in series.stamp_ns]

    cells = series.cell_voltage_v

    def bridge(k: int, with_cells: bool = False, **extra: Any) -> Any:
        return battery_state_message(
            bridge_state(
                stamps[k],
                float(series.voltage_v[k]),
                float(series.current_a[k]),
                temperature_c=float(series.temperature_c[k]),
                design_capacity_ah=battery.nominal_capacity_ah,
                technology=tech,
                **extra,
            ),
            cells[k] if with_cells and cells is not None else (),
        )

    topics: list[tuple[str, str, Any]] = [
        (STATE_TOPIC, BATTERY_STATE, ((stamps[k], bridge(k, True)) for k in range(n)))
    ]
    if series.soc_ref is not None:
        ref = series.soc_ref
        topics.append(
            (
                REFERENCE_TOPIC,
                BATTERY_STATE,
                (
                    (stamps[k], bridge(k, percentage=float(ref[k])))
                    for k in range(n)
                    if math.isfinite(ref[k])
                ),
            )
        )
    for r in results:
        e = r.estimates
        prefix = f"/{e.estimator}" if len(results) > 1 else ""
        rows = [k for k in range(n) if math.isfinite(e.soc[k])]
        full = r.runtime.full if r.runtime is not None else np.zeros(n, dtype=bool)

        def soc_msgs(
            e: EstimateSeries = e, rows: list[int] = rows, full: np.ndarray = full
        ) -> Iterator[Any]:
            for k in rows:
                fields = estimate_state(
                    battery,
                    float(e.soc[k]),
                    stamps[k],
                    float(series.voltage_v[k]),
                    float(series.current_a[k]),
                    float(series.temperature_c[k]),
                    full=bool(full[k]),
                )
                yield stamps[k], battery_state_message(fields)

        def est_msgs(e: EstimateSeries = e, rows: list[int] = rows) -> Iterator[Any]:
            cells = e.cell_fields
            n_cells = 0 if e.cell_soc is None else e.cell_soc.shape[1]
            label = layout_label(e.state_names, cells=n_cells)
            # The vector's soc is the pack's own, as the node's (the usable one is /battery/soc).
            soc = e.soc if e.soc_lumped is None else e.soc_lumped
            std = e.soc_std if e.soc_lumped_std is None else e.soc_lumped_std
            for k in rows:
                row = estimate_row(
                    stamps[k] * 1e-9,
                    float(soc[k]),
                    float(std[k]) ** 2,
                    float(e.voltage_pred_v[k]),
                    float(e.innovation_v[k]),
                    float(e.nis[k]),
                    e.x[k],
                    e.p[k],
                )
                if cells is not None:
                    row += [float(v) for v in cells[k]]
                yield stamps[k], float64_array_message(label, row)

        topics.append((f"{prefix}/battery/soc", BATTERY_STATE, soc_msgs()))
        topics.append((f"{prefix}/battery/soc_estimate", FLOAT64_ARRAY, est_msgs()))
    write_bag(path, topics)


#: The runtime predictions ``--output`` writes after the estimate's columns.
CSV_RUNTIME_COLUMNS = (
    "time_to_empty_s",
    "time_to_empty_std_s",
    "time_to_full_s",
    "max_discharge_current_10s_a",
)
CSV_COLUMNS = (
    "time_s",
    "soc",
    "soc_std",
    "voltage_v",
    "voltage_pred_v",
    "current_a",
    *CSV_RUNTIME_COLUMNS,
    *HEALTH_COLUMNS,
)


def _plot_time_to_empty(ax: Any, series: BatterySeries, results: list[ReplayResult]) -> None:
    """Predicted time to empty (h) with +-2 sigma per estimator, and the actual one."""
    t_h = series.t_s / 3600.0
    target = next(r.runtime.soc_empty for r in results if r.runtime is not None)
    top = 0.0
    if series.soc_ref is not None:
        actual = remaining_time_s(series.t_s, series.soc_ref, target)
        if np.any(np.isfinite(actual)):
            ax.plot(t_h, actual / 3600.0, "k", lw=1.5, label="actual (reference)")
            top = float(np.nanmax(actual)) / 3600.0
        else:
            ax.text(
                0.01,
                0.95,
                f"the reference never reaches SoC {target:g}: no actual time",
                transform=ax.transAxes,
                va="top",
                fontsize=8,
            )
    for r in results:
        if r.runtime is None:
            continue
        tte = r.runtime["time_to_empty_s"] / 3600.0
        std = r.runtime["time_to_empty_std_s"] / 3600.0
        finite = np.isfinite(tte)
        shown = np.where(finite, tte, np.nan)
        (line,) = ax.plot(t_h, shown, lw=1, label=f"{r.estimates.estimator} predicted")
        ax.fill_between(t_h, shown - 2 * std, shown + 2 * std, color=line.get_color(), alpha=0.15)
        if np.any(finite):
            top = max(top, float(np.nanpercentile(shown, 95)))
    ax.set_ylim(0.0, 1.3 * top if top > 0.0 else 1.0)
    ax.set_ylabel(f"time to SoC {target:g} (h)")
    ax.legend(fontsize=8, ncol=3)


def cell_csv_columns(cells: int) -> list[str]:
    """The columns ``--output`` adds with cell voltages: the pack's lumped SoC, then every
    cell's SoC (0..1); ``soc`` and ``soc_std`` are then the usable discharge SoC's."""
    return ["soc_lumped", *(f"cell_soc_{k + 1}" for k in range(cells))]


def write_csv(path: Path, result: ReplayResult) -> None:
    """:data:`CSV_COLUMNS` per sample: the estimate, then the runtime monitor's latest
    prediction (NaN before the first, or when the replay made none; ``inf``: never), then the
    learned health (NaN without ``--learn-health``); with cell voltages
    :func:`cell_csv_columns` after them."""
    e = result.estimates
    n = len(e.t_s)
    rt = result.runtime
    columns = (*CSV_RUNTIME_COLUMNS, *HEALTH_COLUMNS)
    runtime = [rt[c] if rt is not None else np.full(n, math.nan) for c in columns]
    cells: list[np.ndarray] = []
    header = list(CSV_COLUMNS)
    if e.cell_soc is not None and e.soc_lumped is not None:
        cells = [e.soc_lumped, *(e.cell_soc[:, k] for k in range(e.cell_soc.shape[1]))]
        header += cell_csv_columns(e.cell_soc.shape[1])
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in zip(
            e.t_s,
            e.soc,
            e.soc_std,
            e.voltage_v,
            e.voltage_pred_v,
            e.current_a,
            *runtime,
            *cells,
            strict=True,
        ):
            w.writerow([f"{v:.6g}" if k else f"{v:.3f}" for k, v in enumerate(row)])


def error_axis_limit_pct(errors_pct: list[np.ndarray]) -> float:
    """The error panel's half-range (points): wide enough for every estimator but the worst
    one, between ``ERROR_AXIS_MIN_PCT`` and ``ERROR_AXIS_MAX_PCT``; an estimator beyond it is
    clipped and marked, so one diverged filter does not flatten the others into a line."""
    peaks = sorted(float(np.nanmax(np.abs(e))) for e in errors_pct if np.any(np.isfinite(e)))
    if not peaks:
        return ERROR_AXIS_MIN_PCT
    second = peaks[-2] if len(peaks) > 1 else peaks[-1]
    limit = 1.2 * (peaks[-1] if peaks[-1] <= 2.0 * second else second)
    return min(max(limit, ERROR_AXIS_MIN_PCT), ERROR_AXIS_MAX_PCT)


def _has_predictions(results: list[ReplayResult]) -> bool:
    return any(
        r.runtime is not None and np.any(np.isfinite(r.runtime["time_to_empty_s"])) for r in results
    )


def plot_results(path: Path, series: BatterySeries, results: list[ReplayResult]) -> None:
    """SoC vs reference with +-2 sigma, the error, and measured vs predicted voltage
    (seed 000 Figs. 11-13), one colour per estimator. The error axis is clipped
    (:func:`error_axis_limit_pct`); a clipped estimator is named in the panel with its peak.
    With the runtime monitor's predictions, a fourth panel: the predicted time to empty with
    +-2 sigma against the actual one (the time until the reference SoC reaches the target,
    where it does)."""
    import matplotlib  # noqa: PLC0415 (only for plots)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    runtime_panel = _has_predictions(results)
    rows = 4 if runtime_panel else 3
    fig, axes = plt.subplots(rows, 1, figsize=(10, 2.6 * rows + 2.2), sharex=True)
    t_h = series.t_s / 3600.0
    if series.soc_ref is not None:
        axes[0].plot(t_h, 100 * series.soc_ref, "k", lw=1.5, label="reference")
    axes[2].plot(t_h, series.voltage_v, color="0.6", lw=0.5, label="measured")
    errors = (
        [100 * (r.estimates.soc - series.soc_ref) for r in results]
        if series.soc_ref is not None
        else []
    )
    limit = error_axis_limit_pct(errors)
    clipped: list[str] = []
    for k, r in enumerate(results):
        e = r.estimates
        (line,) = axes[0].plot(t_h, 100 * e.soc, lw=1, label=e.estimator)
        if e.cell_soc is not None:  # the cells, thin, in the estimator's colour
            axes[0].plot(t_h, 100 * e.cell_soc, lw=0.4, color=line.get_color(), alpha=0.6)
            if series.cell_soc_ref is not None and k == 0:
                axes[0].plot(t_h, 100 * series.cell_soc_ref, "k:", lw=0.5)
        axes[0].fill_between(
            t_h,
            100 * (e.soc - 2 * e.soc_std),
            100 * (e.soc + 2 * e.soc_std),
            color=line.get_color(),
            alpha=0.15,
        )
        if errors:
            err = errors[k]
            axes[1].plot(t_h, np.clip(err, -limit, limit), lw=1, color=line.get_color())
            peak = float(np.nanmax(np.abs(err))) if np.any(np.isfinite(err)) else 0.0
            if peak > limit:
                clipped.append(f"{e.estimator} (peak {peak:.0f})")
        if np.any(np.isfinite(e.voltage_pred_v)):
            axes[2].plot(
                t_h,
                e.voltage_pred_v,
                lw=0.7,
                color=line.get_color(),
                label=f"{e.estimator} predicted",
            )
    axes[0].set_ylabel("SoC (%)")
    axes[0].legend(fontsize=8, ncol=3)
    axes[1].set_ylabel("SoC error (points)")
    axes[1].set_ylim(-1.05 * limit, 1.05 * limit)
    for y in (-2, 2):
        axes[1].axhline(y, color="k", ls=":", lw=0.8)
    if clipped:
        axes[1].text(
            0.01,
            0.97,
            f"clipped at ±{limit:.1f}: " + ", ".join(clipped),
            transform=axes[1].transAxes,
            va="top",
            fontsize=8,
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.7"},
        )
    axes[2].set_ylabel("voltage (V)")
    axes[2].legend(fontsize=8, ncol=3)
    if runtime_panel:
        _plot_time_to_empty(axes[3], series, results)
    axes[-1].set_xlabel("time (h)")
    fig.suptitle(results[0].input_name)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
