"""The OCV hysteresis on the PyBaMM hysteretic LFP pack (``bags/lfp_hysteresis_test``:
16 mV per cell, 64 mV for the pack, the branch change 63 % done after 2 % of SoC).

The identification is run on the bundled two-way test; the hybrid is then replayed on that same
test: a behaviour check (the charge branch read as such), not a validation (the missions of
``benchmarks/studies/hysteresis.py`` are; docs/accuracy.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT, bag_path, load_benchmark

from soc_estimator_ros.identification.cli import main as identify_main
from soc_estimator_ros.identification.hysteresis import fit_hysteresis
from soc_estimator_ros.params import load_battery_params
from soc_estimator_ros.recordings import read_recording

STUDY = load_benchmark("studies/hysteresis")
LFP = load_battery_params(REPO_ROOT / "config" / "lfp_12v6ah.yaml")
SIM_GAP_V = 0.064  # the simulator's (bag.yaml: gap_pack_v)
SIM_RATE = 50.0  # its e-folding charge, 2 % of SoC, in Plett's gamma


@pytest.fixture(scope="module")
def two_way():
    return read_recording(bag_path("lfp_hysteresis_test"))


def test_the_simulators_hysteresis_is_identified(two_way) -> None:
    meta = yaml.safe_load((bag_path("lfp_hysteresis_test") / "bag.yaml").read_text())
    assert meta["hysteresis"]["gap_pack_v"] == SIM_GAP_V
    fit = fit_hysteresis(LFP, two_way, [])
    assert fit.hysteresis is not None
    # Within three of the fit's own standard errors of the simulator's gap (measured: 77 mV,
    # se 5.8: the model's OCV error moves by +-5 mV between the rests' SoCs, and the three
    # transition rests per direction sit where it differs).
    assert abs(fit.hysteresis.gap_v - SIM_GAP_V) < 3.0 * fit.gap_se_v
    # The rate to within a factor of 2 (measured 35): three rests per transition.
    assert SIM_RATE / 2 < fit.hysteresis.rate_per_soc < 2 * SIM_RATE
    # The bundled file was identified on the same cell without hysteresis: its OCV is the
    # middle of the branches, half the gap below the charge branch (5 mV: the model's OCV
    # error between the rests' SoCs, as above).
    assert fit.offset_v == pytest.approx(-SIM_GAP_V / 2, abs=0.005)


def test_after_a_charge_the_voltage_is_read_on_the_charge_branch(two_way) -> None:
    plain, hyst, _ = STUDY.identified(two_way)
    first_charge = int(np.argmax(two_way.current_a < -0.5))
    worst = {}
    for name, battery in (("plain", plain), ("hysteresis", hyst)):
        soc, _ = STUDY.run(battery, two_way, "hybrid", 1.0)  # full: on the charge branch
        worst[name] = float(np.max(np.abs(soc - two_way.soc_ref)[first_charge:]))
    # Measured: 19.7 points without (the charge branch's 64 mV read as SoC on the plateau),
    # 1.2 with (coulomb counting: 1.1); the bounds leave a factor of 2 either way.
    assert worst["plain"] > 0.10
    assert worst["hysteresis"] < 0.025


def test_soc_identify_writes_the_hysteresis_only_from_a_two_way_test(tmp_path: Path) -> None:
    args = [
        str(bag_path("lfp_pulse_test")),
        "--chemistry",
        "lfp",
        "--slow-discharge",
        str(bag_path("lfp_slow_discharge")),
    ]
    with_test = tmp_path / "with.yaml"
    assert (
        identify_main(
            [
                *args,
                "--hysteresis-test",
                str(bag_path("lfp_hysteresis_test")),
                "--output",
                str(with_test),
            ]
        )
        == 0
    )
    written = load_battery_params(with_test)
    assert written.hysteresis is not None and written.hysteresis.gap_v > 0.03
    # Without the test, none: not even from a template that has one.
    template = tmp_path / "template.yaml"
    data = yaml.safe_load(with_test.read_text())
    template.write_text(yaml.safe_dump(data))
    without = tmp_path / "without.yaml"
    assert identify_main([*args, "--template", str(template), "--output", str(without)]) == 0
    assert load_battery_params(without).hysteresis is None
