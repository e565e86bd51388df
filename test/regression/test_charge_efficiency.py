"""benchmarks/studies/charge_efficiency.py on the bundled corpus validation bags: the battery
files hold the coulomb efficiency on charge that their packs' recordings show (issue 24,
item 4). The SLA file's value is the median over the corpus' tuning half (9 missions that
charge: 0.9840-0.9995, median 0.9945); the bundled validation bags check it."""

from __future__ import annotations

import pytest
from conftest import bag_path, load_benchmark

from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_recording
from soc_estimator_ros.replay.run import battery_file_for

#: Bundled validation missions with a dock charge (bags/README.md).
CHARGED = [
    "sla_validation_1003",
    "sla_validation_1037",
    "lfp_validation_1001",
    "lfp_validation_1005",
]


@pytest.mark.parametrize("bag", CHARGED)
def test_file_efficiency_is_what_the_recording_shows(bag: str) -> None:
    study = load_benchmark("studies/charge_efficiency")
    measured = study.measure(bag_path(bag))
    assert measured is not None and measured.fit.charge_ah >= study.MIN_CHARGE_AH
    battery = load_battery_params(battery_file_for(read_recording(bag_path(bag))))
    assert measured.file_efficiency == battery.coulomb_efficiency_charge
    # 0.012: the tuning half's spread about its median (0.9840-0.9995 about 0.9945 for SLA,
    # 0.9946-1.0014 about 1.000 for LFP, whose file keeps 0.99); the SLA file's earlier 0.9
    # was 0.09 off.
    assert measured.fit.efficiency == pytest.approx(battery.coulomb_efficiency_charge, abs=0.012)


def test_the_script_prints_the_median(capsys: pytest.CaptureFixture[str]) -> None:
    study = load_benchmark("studies/charge_efficiency")
    paths = [str(bag_path(b)) for b in CHARGED[:2]]
    assert study.main(paths) == 0
    out = capsys.readouterr().out
    assert "| sla_validation_1003 |" in out and "median eta over 2 recordings" in out
