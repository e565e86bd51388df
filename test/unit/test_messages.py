"""messages.py: the one BatteryState rule (status, health, technology) and the estimate
vector, as the node publishes them and soc_replay --output-bag writes them."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import REPO_ROOT

from soc_estimator_ros import messages as m
from soc_estimator_ros.estimators import make_estimator
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import battery_state_message

SLA = load_battery_params(REPO_ROOT / "config" / "sla_12v5ah.yaml")
LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")


@pytest.mark.parametrize(
    ("current_core_a", "status"),
    [
        (2.0, m.STATUS_DISCHARGING),
        (-2.0, m.STATUS_CHARGING),
        (0.05, m.STATUS_NOT_CHARGING),
        (-0.3, m.STATUS_NOT_CHARGING),  # a charge below Nav2's 0.5 A docking threshold
        (-0.6, m.STATUS_CHARGING),
    ],
)
def test_status_from_the_current_with_a_dead_band(current_core_a, status) -> None:
    fields = m.estimate_state(SLA, 0.5, 0, 12.5, current_core_a, idle_current_a=0.1)
    assert fields.power_supply_status == status
    assert fields.current == -current_core_a  # ROS sign: negative while discharging


def test_full_and_stale_states() -> None:
    full = m.estimate_state(SLA, 1.0, 0, 14.35, -0.1, full=True)
    assert full.power_supply_status == m.STATUS_FULL == 4
    stale = m.estimate_state(SLA, 0.37, 0, 12.0, 3.0, stale=True)
    assert stale.power_supply_status == m.STATUS_UNKNOWN
    assert stale.power_supply_health == m.HEALTH_UNKNOWN
    assert stale.percentage == pytest.approx(0.37)  # carried, never NaN (Nav2's IsBatteryLow)
    assert math.isnan(stale.voltage) and math.isnan(stale.current)
    assert math.isnan(stale.temperature)


def test_runtime_vector_is_labelled() -> None:
    values = {k: float(i) for i, k in enumerate(m.RUNTIME_FIELDS)}
    data = m.runtime_vector(values)
    label = m.runtime_layout_label()
    assert label.startswith("fields:stamp_s,time_to_empty_s,time_to_empty_std_s,time_to_full_s")
    msg = SimpleNamespace(layout=SimpleNamespace(dim=[SimpleNamespace(label=label)]), data=data)
    assert m.decode_runtime(msg) == values


def test_health_and_capacity_fields() -> None:
    lim = SLA.limits
    assert m.supply_health(lim.voltage_max_v + 0.1, 25.0, lim) == m.HEALTH_OVERVOLTAGE
    assert m.supply_health(lim.voltage_min_v - 0.1, 25.0, lim) == m.HEALTH_DEAD
    assert m.supply_health(12.5, lim.temperature_min_c - 1, lim) == m.HEALTH_COLD
    assert m.supply_health(12.5, lim.temperature_max_c + 1, lim) == m.HEALTH_OVERHEAT
    assert m.supply_health(12.5, math.nan, lim) == m.HEALTH_GOOD  # unknown is not judged
    f = m.estimate_state(SLA, 0.4, 0, 12.5, 1.0)
    assert f.charge == pytest.approx(0.4 * SLA.capacity_ah)
    assert f.capacity == SLA.capacity_ah and f.design_capacity == SLA.nominal_capacity_ah
    assert f.power_supply_technology == m.TECHNOLOGY_BY_CHEMISTRY["sla"] == 8  # VRLA in Jazzy
    assert m.chemistry_of_technology(4) == "lfp" and m.chemistry_of_technology(99) is None


def test_the_rosbags_message_carries_every_field() -> None:
    f = m.estimate_state(SLA, 0.4, 1_500_000_000_123, 12.5, 1.0, 20.0, serial_number="S1")
    msg = battery_state_message(f)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1500, 123)
    assert msg.percentage == pytest.approx(0.4) and msg.serial_number == "S1"
    assert msg.power_supply_health == m.HEALTH_GOOD and len(msg.cell_voltage) == 0


def test_estimate_vector_round_trip() -> None:
    est = make_estimator("hybrid", SLA, 0.6, 0.1).step(0.0, 1.0, 12.5, 25.0)
    labels = m.estimate_labels(est.state_names)
    data = m.estimate_vector(12.0, est)
    assert len(data) == len(labels) == 7 + len(est.x) + len(est.x) ** 2

    class Dim:
        label = m.layout_label(est.state_names)

    class Layout:
        dim = [Dim()]

    class Msg:
        layout = Layout()

    Msg.data = np.asarray(data)
    decoded = m.decode_estimate(Msg)
    assert decoded["stamp_s"] == 12.0 and decoded["soc"] == est.soc
    assert decoded["soc_std"] == pytest.approx(math.sqrt(est.soc_var))


def test_estimate_labels_and_vector_with_cells() -> None:
    """The ``cell.*`` labels follow the health's, in the order of ``CellEstimate.fields``;
    ``soc`` stays the pack's lumped estimate (docs/cells.md)."""
    from soc_estimator_ros.cells import CellBank

    est = make_estimator("hybrid", LFP, 0.6, 0.1).step(0.0, 1.0, 13.1, 25.0)
    bank = CellBank(LFP, 4)
    cells = bank.step(0.0, 1.0, np.array([3.27, 3.28, 3.27, 3.29]), est.soc, est.soc_var)
    labels = m.estimate_labels(est.state_names, health=False, cells=4)
    plain = m.estimate_labels(est.state_names)
    assert labels[: len(plain)] == plain
    assert labels[len(plain) :] == [
        *(f"cell.soc_{k}" for k in range(1, 5)),
        *(f"cell.soc_std_{k}" for k in range(1, 5)),
        "cell.usable_soc",
        "cell.usable_soc_std",
        "cell.usable_charge_soc",
        "cell.weakest",
        "cell.imbalance_soc",
        "cell.spread_v",
    ]
    data = m.estimate_vector(3.0, est, None, cells)
    assert len(data) == len(labels)
    named = dict(zip(labels, data, strict=True))
    assert named["soc"] == est.soc
    assert named["cell.usable_soc"] == cells.usable_soc
    assert [named[f"cell.soc_{k}"] for k in range(1, 5)] == list(cells.soc)
    # Without cells the vector is the one it always was.
    assert m.estimate_vector(3.0, est) == data[: len(plain)]


def test_pack_temperature_is_the_packs_else_the_mean_of_its_cells() -> None:
    nan = math.nan
    assert m.pack_temperature_c(21.5, [4.0, 6.0]) == 21.5  # the pack's own reading wins
    assert m.pack_temperature_c(nan, [4.0, 6.0, nan, 5.0]) == pytest.approx(5.0)
    assert math.isnan(m.pack_temperature_c(nan, []))
    assert math.isnan(m.pack_temperature_c(nan, [nan, nan]))
