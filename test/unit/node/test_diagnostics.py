"""node/diagnostics.py without ROS: the guard's weight and the count in the report."""

from __future__ import annotations

from dataclasses import replace

from conftest import REPO_ROOT

from soc_estimator_ros.node.diagnostics import Diagnostics, Level
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.tracking import GateConfig, Sample, Tracker, TrackerConfig

SLA = load_battery_params(REPO_ROOT / "config" / "sla_12v5ah.yaml")
S = 1_000_000_000


def report_after(temperature_c: float):
    """20 minutes at 0.5 A with a voltage 0.3 SoC below what the counted SoC gives. Item 11
    off: it would keep the UKF with the count for the first ``bias_tau_s`` (the next test)."""
    tuning = {**SLA.filters["hybrid"], "persistent_innovation_sigma": 0.0}
    tr = Tracker(
        replace(SLA, filters={**SLA.filters, "hybrid": tuning}),
        GateConfig.from_limits(SLA.limits),
        TrackerConfig(estimator="hybrid", initial_soc=0.8, initial_soc_std=0.02),
    )
    v = SLA.thevenin_model().ocv.ocv(0.5)
    for k in range(12_000):
        tr.process(Sample(k * S // 10, 0.5, v, temperature_c))
    return Diagnostics(tr, "sla.yaml", 0.0).report(1200.0, stale_timeout_s=1e9)


def test_a_weighed_out_model_is_a_warning_with_the_count_beside_it() -> None:
    # -20 degC: 22 degC below the SLA file's 5-25 degC (margin 3): the guard keeps the count.
    rep = report_after(-20.0)
    values = dict(rep.values)
    assert rep.level is Level.WARN and "voltage model weighed out" in rep.message, rep.message
    assert "extrapolating" in rep.message
    assert float(values["model_weight"]) < 0.5
    # The published SoC is the count's (the test_guard.py case), the model's is far below.
    assert abs(float(values["soc"]) - float(values["soc_count"])) < 0.005
    assert float(values["soc_model"]) < float(values["soc_count"]) - 0.1


def test_no_warning_where_the_model_is_trusted() -> None:
    rep = report_after(25.0)  # inside the identified range: the count follows the UKF
    assert "weighed out" not in rep.message, rep.message
    assert float(dict(rep.values)["model_weight"]) >= 0.5


LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")


def lfp_load_report(
    error_v: float,
    soc: float = 0.42,
    soc_std: float = 0.015,
    current_a: float = 3.0,
    samples: int = 1200,
):
    """``samples`` at 10 Hz (two minutes) at ``current_a`` (3 A) with the voltage ``error_v``
    off the LFP file's model, from the true SoC ``soc`` (0.42) given with ``soc_std`` (0.015:
    test_estimators.py's item 11 case); the report and the truth."""
    tr = Tracker(
        LFP,
        GateConfig.from_limits(LFP.limits),
        TrackerConfig(estimator="hybrid", initial_soc=soc, initial_soc_std=soc_std),
    )
    model = LFP.thevenin_model()
    x = model.rested_state(soc)
    for k in range(samples):
        v = model.terminal_voltage(x, current_a) + error_v
        tr.process(Sample(k * S // 10, current_a, v, 25.0))
        x = model.step(x, current_a, 0.1)
    report = Diagnostics(tr, "lfp.yaml", 0.0).report(samples / 10, stale_timeout_s=1e9)
    return report, float(x[0])


def test_a_persistent_model_error_is_a_warning() -> None:
    """Hybrid item 11: 0.3 V below the model: WARN with the averaged innovation, and the
    published SoC stays with the start."""
    rep, true_soc = lfp_load_report(-0.3)
    values = dict(rep.values)
    assert rep.level is Level.WARN and "voltage model off by" in rep.message, rep.message
    assert values["model_error_persistent"] == "true"
    # The averaged innovation is the 0.3 V the model misses, less what the filter took in
    # (its bias state): measured -0.26 V; bound 0.2 V.
    assert float(values["innovation_avg_v"]) < -0.2
    assert abs(float(values["soc"]) - true_soc) < 0.01  # 1 point, test_estimators.py's bound


def test_no_persistent_error_where_the_model_holds() -> None:
    rep, _ = lfp_load_report(0.0)
    assert "voltage model off" not in rep.message, rep.message
    assert dict(rep.values)["model_error_persistent"] == "false"


def test_a_wide_starts_grid_is_reported_until_it_narrows() -> None:
    """Hybrid item 12: the SoC's grid posterior std while it runs, nan otherwise (the item-11
    case above starts sure: no grid)."""
    rep, _ = lfp_load_report(0.0)
    assert dict(rep.values)["soc_grid_std"] == "nan"
    # ten seconds at rest on the plateau, the start given wide: the grid stays wide
    rep, _ = lfp_load_report(0.0, soc=0.55, soc_std=0.1, current_a=0.0, samples=100)
    values = dict(rep.values)
    # the plateau tells little in ten seconds: the grid's std is the prior's within a few points
    assert 0.05 < float(values["soc_grid_std"]) <= 0.1
    assert float(values["soc_std"]) >= float(values["soc_grid_std"]) - 1e-9


def cells_report(cell_v: tuple[float, ...], bad_samples: int = 0):
    """Ten samples of a 4S LFP pack at rest with these cell voltages, ``bad_samples`` of them
    with cell 2 unreadable (NaN)."""
    tr = Tracker(LFP, GateConfig.from_limits(LFP.limits), TrackerConfig(initial_soc=0.6))
    diag = Diagnostics(tr, "lfp.yaml", 0.0)
    for k in range(10):
        v = list(cell_v)
        if k < bad_samples:
            v[1] = float("nan")
        tr.process(Sample(k * S, 0.3, sum(cell_v), 25.0, cell_voltage_v=tuple(v)))
    return diag.report(10.0, stale_timeout_s=1e9)


def test_no_cell_values_without_cell_voltages() -> None:
    rep = report_after(25.0)
    assert not any(k.startswith("cell") for k, _ in rep.values)


def test_cell_values_and_a_rejected_reading() -> None:
    rep = cells_report((3.27, 3.27, 3.27, 3.27), bad_samples=2)
    values = dict(rep.values)
    assert values["cells"] == "4" and values["cell_rejected_2"] == "2"
    assert values["cell_rejected_1"] == "0" and "weakest_cell" in values
    assert rep.level is Level.WARN and "2 cell readings rejected recently" in rep.message


def test_cell_spread_and_limits() -> None:
    # 0.15 V apart: above the default 0.10 V warn, below the 0.20 V error.
    rep = cells_report((3.27, 3.27, 3.27, 3.42))
    assert rep.level is Level.WARN and "cell voltage spread 0.150 V >= 0.1 V" in rep.message
    # A cell above 3.65 V (14.6 V / 4): over-voltage, an error.
    rep = cells_report((3.27, 3.27, 3.27, 3.70))
    assert rep.level is Level.ERROR and "cell 4 overvoltage 3.700 V" in rep.message
    rep = cells_report((3.27, 2.40, 3.27, 3.27))
    assert rep.level is Level.ERROR and "cell 2 undervoltage 2.400 V" in rep.message
