"""Battery parameter files: the bundled files load, and every kind of bad file is rejected
with one message that names the file, the key, the value and what was expected."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT

from soc_estimator_ros.models import SurfaceLag
from soc_estimator_ros.params import (
    ParamFileError,
    battery_params_to_dict,
    load_battery_params,
    parse_battery_params,
)

CONFIG = REPO_ROOT / "config"
# Battery files (the node's ROS params file, soc_estimator_node.yaml, lives beside them).
BUNDLED = sorted(p for p in CONFIG.glob("*.yaml") if "schema_version" in p.read_text())


def base() -> dict:
    """A valid file with one temperature: the LFP file's 25 degC tables (every bundled file has
    a temperature axis), as a robot owner's first file identified at one temperature is."""
    tree = yaml.safe_load((CONFIG / "lfp_12v6ah.yaml").read_text())
    for table in (tree["ocv"], tree["thevenin"]):
        temps = table.pop("temperature_c", [25.0])
        row = temps.index(25.0)
        table.pop("offset_v", None)
        tables = [table, table.get("kinetic", {}), *table.get("branches", [])]
        for node in tables:
            for key, value in node.items():
                if isinstance(value, list) and value and isinstance(value[0], list):
                    node[key] = value[row]
    return tree


@pytest.mark.parametrize("path", BUNDLED, ids=lambda p: p.name)
def test_bundled_files_load_and_round_trip(path: Path) -> None:
    params = load_battery_params(path)
    assert params.capacity_ah > 0 and params.cells_in_series >= 1
    again = parse_battery_params(battery_params_to_dict(params), "round-trip")
    assert again == params


def test_bundled_chemistries_present() -> None:
    chems = {load_battery_params(p).chemistry for p in BUNDLED}
    assert {"sla", "lfp", "li_ion"} <= chems


def _set(tree: dict, dotted: str, value) -> None:
    node = tree
    parts = dotted.replace("]", "").replace("[", ".").split(".")
    for part in parts[:-1]:
        node = node[int(part)] if part.isdigit() else node[part]
    last = parts[-1]
    if value is _DELETE:
        del node[int(last) if last.isdigit() else last]
    elif last.isdigit():
        node[int(last)] = value
    else:
        node[last] = value


_DELETE = object()

BAD = [
    # (what to change, new value, key named in the message, expectation fragment)
    ("nominal_capacity_ah", _DELETE, "nominal_capacity_ah", "required"),
    ("limits.voltage_min_v", _DELETE, "limits.voltage_min_v", "required"),
    ("thevenin.branches[0].c_f", _DELETE, "thevenin.branches[0].c_f", "required"),
    ("nominal_capacity_ah", -5.0, "nominal_capacity_ah", ">= 0.001"),
    ("nominal_capacity_ah", "five", "nominal_capacity_ah", "a number"),
    ("nominal_capacity_ah", float("inf"), "nominal_capacity_ah", "finite"),
    ("limits.soc_min", 1.5, "limits.soc_min", "<= 1"),
    ("limits.voltage_max_v", 9.0, "limits.voltage_max_v", "> limits.voltage_min_v"),
    ("coulomb_efficiency_charge", 1.2, "coulomb_efficiency_charge", "<= 1"),
    ("cells_in_series", 0, "cells_in_series", "integer >= 1"),
    ("chemistry", "nimh", "chemistry", "one of sla, lfp, li_ion"),
    ("schema_version", 7, "schema_version", "1"),
    ("ocv.voltage_v[4]", 1.0, "ocv.voltage_v[4]", "strictly increasing"),
    ("ocv.soc[2]", 0.0, "ocv.soc[2]", "strictly increasing"),
    ("ocv.soc[10]", 1.2, "ocv.soc[10]", "<= 1"),
    ("ocv.voltage_v", [12.0, 12.5], "ocv.voltage_v", "one per ocv.soc point"),
    ("rest_ocv.voltage_v[4]", 1.0, "rest_ocv.voltage_v[4]", "strictly increasing"),
    ("rest_ocv.soc[3]", -0.1, "rest_ocv.soc[3]", ">= 0"),
    ("rest_ocv.voltage_v", [12.0, 12.5], "rest_ocv.voltage_v", "one per rest_ocv.soc point"),
    ("rest_ocv", [1, 2], "rest_ocv", "a mapping"),
    ("rc_model.r_b_ohm", -0.01, "rc_model.r_b_ohm", "> 0"),
    ("rc_model.c_s_f", 0.0, "rc_model.c_s_f", ">= 1e-06"),
    ("thevenin.r0_ohm[1]", -0.03, "thevenin.r0_ohm[1]", "> 0"),
    ("thevenin.branches[1].c_f[2]", -1.0, "thevenin.branches[1].c_f[2]", ">= 1e-06"),
    ("thevenin.branches[0].r_ohm", [0.01, 0.01], "thevenin.branches[0].r_ohm", "one per"),
    ("thevenin.soc", [0.2, 0.1, 0.8, 1.0], "thevenin.soc[1]", "strictly increasing"),
    ("thevenin.branches", [], "thevenin.branches", "1 to 3 RC branches"),
    ("thevenin.fitted_c_rate_max", 0.0, "thevenin.fitted_c_rate_max", ">= 0.001"),
    ("filters.rc_kf_paper.r", -0.8, "filters.rc_kf_paper.r", "> 0"),
    ("filters.rc_kf_paper.q_diag", [1e-5, "x", 0.9], "filters.rc_kf_paper.q_diag[1]", "number"),
    # Absurd values (params.ABSURD, ABSURD_TUNING), each once ran into NaN estimates or
    # an exception on every sample; the LFP pack has 4 cells in series.
    ("thevenin.r0_ohm[1]", 1e300, "thevenin.r0_ohm[1]", "<= 400"),
    ("thevenin.branches[1].c_f[2]", 1e300, "thevenin.branches[1].c_f[2]", "<= 1e+10"),
    ("thevenin.branches[0].i_sat_a[0]", 1e300, "thevenin.branches[0].i_sat_a[0]", "<= 100000"),
    ("thevenin.kinetic.a_v[3]", 5.0, "thevenin.kinetic.a_v[3]", "<= 4"),
    ("rc_model.r_b_ohm", 1e300, "rc_model.r_b_ohm", "<= 400"),
    ("filters.hybrid.model_soc_std", 1e300, "filters.hybrid.model_soc_std", "<= 1e+12"),
    ("capacity_ah", 1e-300, "capacity_ah", ">= 0.001"),
    ("limits.voltage_max_v", 1e300, "limits.voltage_max_v", "<= 40"),
    ("ocv.voltage_v[5]", 1e300, "ocv.voltage_v[5]", "<= 40"),
    ("thevenin.kinetic.i0_a[0]", 1e-300, "thevenin.kinetic.i0_a[0]", ">= 1e-06"),
    ("thevenin.branches[1].c_f[2]", 1e-300, "thevenin.branches[1].c_f[2]", ">= 1e-06"),
    ("rc_model.c_s_f", 1e6, "rc_model.c_s_f", "the model is unstable otherwise"),
    ("limits", [1, 2], "limits", "a mapping"),
]


@pytest.mark.parametrize(("key", "value", "named", "expected"), BAD, ids=[b[0] for b in BAD])
def test_bad_file_rejected_with_clear_message(tmp_path, key, value, named, expected) -> None:
    tree = copy.deepcopy(base())
    _set(tree, key, value)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(tree))
    with pytest.raises(ParamFileError) as info:
        load_battery_params(path)
    message = str(info.value)
    assert str(path) in message
    assert f"{named} = " in message
    assert expected in message
    assert info.value.key == named


def test_temperature_tables_must_have_one_row_per_temperature(tmp_path) -> None:
    tree = base()
    tree["thevenin"]["temperature_c"] = [0.0, 25.0]
    path = tmp_path / "t.yaml"
    path.write_text(yaml.safe_dump(tree))
    with pytest.raises(ParamFileError, match=r"thevenin.r0_ohm = .*2 rows"):
        load_battery_params(path)
    # Two rows everywhere makes it valid, and the temperature axis is used.
    th = tree["thevenin"]
    for node in [th, th.get("kinetic", {}), *th["branches"]]:
        for key, value in node.items():
            if key not in ("soc", "temperature_c", "branches") and isinstance(value, list):
                node[key] = [value, value]
    th["r0_ohm"][0] = [2 * v for v in th["r0_ohm"][1]]
    path.write_text(yaml.safe_dump(tree))
    params = load_battery_params(path)
    assert params.thevenin.r0_ohm.at(0.5, 0.0) == pytest.approx(2 * params.thevenin.r0_ohm.at(0.5))


def test_ocv_temperature_shift_is_validated_and_round_trips(tmp_path) -> None:
    tree = base()
    n = len(tree["ocv"]["soc"])
    tree["ocv"]["temperature_c"] = [0.0, 25.0]
    tree["ocv"]["offset_v"] = [[-0.02] * n]
    path = tmp_path / "t.yaml"
    path.write_text(yaml.safe_dump(tree))
    with pytest.raises(ParamFileError, match=r"ocv.offset_v = .*2 rows"):
        load_battery_params(path)
    tree["ocv"]["offset_v"] = [[-0.02] * n, [0.0] * (n - 1)]
    path.write_text(yaml.safe_dump(tree))
    with pytest.raises(ParamFileError, match=rf"ocv.offset_v\[1\] = .*{n} values"):
        load_battery_params(path)
    tree["ocv"]["offset_v"] = [[-0.02] * n, [0.0] * n]
    path.write_text(yaml.safe_dump(tree))
    params = load_battery_params(path)
    table = params.ocv.offset_table()
    assert table is not None
    assert table.at(0.5, 0.0) == pytest.approx(-0.02)
    assert table.at(0.5, 12.5) == pytest.approx(-0.01)  # linear in temperature
    again = parse_battery_params(battery_params_to_dict(params))
    assert again.ocv == params.ocv


def test_surface_lag_is_validated_and_round_trips(tmp_path) -> None:
    tree = base()
    path = tmp_path / "t.yaml"
    good = {"gain_soc_per_a": [0.004, 0.008], "tau_s": [60.0, 600.0], "soc_max": [1.0, 0.9]}
    for change, named in (
        ({"gain_soc_per_a": [-0.001, 0.008]}, r"gain_soc_per_a\[0\]"),
        ({"tau_s": [60.0, 0.0]}, r"tau_s\[1\]"),
        ({"soc_max": [1.0, 1.5]}, r"soc_max\[1\]"),
        ({"tau_s": None}, "tau_s"),  # missing
        ({"gain_soc_per_a": 0.004}, "gain_soc_per_a"),  # a list per key, one entry per mode
        ({"gain_soc_per_a": [], "tau_s": [], "soc_max": []}, "gain_soc_per_a"),
        ({"tau_s": [60.0]}, "tau_s"),
        ({"soc_max": [1.0]}, "soc_max"),
    ):
        bad = {k: v for k, v in {**good, **change}.items() if v is not None}
        tree["thevenin"]["surface_lag"] = bad
        path.write_text(yaml.safe_dump(tree))
        with pytest.raises(ParamFileError, match=rf"thevenin.surface_lag.{named}"):
            load_battery_params(path)
    tree["thevenin"]["surface_lag"] = good
    path.write_text(yaml.safe_dump(tree))
    params = load_battery_params(path)
    assert params.thevenin.surface_lag == SurfaceLag((0.004, 0.008), (60.0, 600.0), (1.0, 0.9))
    assert params.name == tree["name"]  # the lag's keys are not the file's
    again = parse_battery_params(battery_params_to_dict(params))
    assert again.thevenin.surface_lag == params.thevenin.surface_lag


def test_unreadable_and_malformed_yaml(tmp_path) -> None:
    with pytest.raises(ParamFileError, match="readable YAML file"):
        load_battery_params(tmp_path / "missing.yaml")
    bad = tmp_path / "broken.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(ParamFileError, match="valid YAML"):
        load_battery_params(bad)
    bad.write_text("- just\n- a list\n")
    with pytest.raises(ParamFileError, match="a mapping"):
        load_battery_params(bad)


def test_levels_and_charge_sections_are_optional_validated_and_round_trip() -> None:
    from soc_estimator_ros.params import ChargeSettings, LevelSettings

    tree = base()
    params = parse_battery_params(tree)
    assert params.levels == LevelSettings() and params.charge == ChargeSettings()
    for section, change, named in (
        ("levels", {"warn": 0.3}, "levels.warn"),  # unknown key (a typo of warn_soc)
        ("levels", {"warn_soc": 1.5}, "levels.warn_soc"),
        ("levels", {"warn_soc": 0.2, "critical_soc": 0.3}, "levels.critical_soc"),
        ("levels", {"debounce_s": -1}, "levels.debounce_s"),
        ("charge", {"voltage_v": 20.0}, "charge.voltage_v"),  # above limits.voltage_max_v
        ("charge", {"voltage_tolerance_v": 0.0}, "charge.voltage_tolerance_v"),
        ("charge", {"taper_c_rate": 0.0}, "charge.taper_c_rate"),
        ("charge", "14.4", "charge"),
    ):
        bad = copy.deepcopy(tree)
        bad[section] = change
        with pytest.raises(ParamFileError, match=named):
            parse_battery_params(bad)
    tree["levels"] = {"warn_soc": 0.35, "critical_soc": 0.25, "debounce_s": 20.0}
    tree["charge"] = {"voltage_v": 14.2, "hold_s": 30.0}
    params = parse_battery_params(tree)
    assert params.levels == LevelSettings(warn_soc=0.35, critical_soc=0.25, debounce_s=20.0)
    assert params.charge == ChargeSettings(voltage_v=14.2, hold_s=30.0)
    dumped = battery_params_to_dict(params)
    assert dumped["levels"] == tree["levels"] and dumped["charge"] == tree["charge"]
    assert parse_battery_params(dumped) == params


def test_cells_section_is_optional_validated_and_round_trips() -> None:
    from soc_estimator_ros.params import CellSettings

    tree = base()
    params = parse_battery_params(tree)
    assert params.cells == CellSettings()
    assert "cells" not in battery_params_to_dict(params)  # defaults are not written
    for change, named in (
        ({"imbalance": 0.1}, "cells.imbalance"),  # unknown key
        ({"imbalance_soc_warn": 0.2, "imbalance_soc_error": 0.1}, "cells.imbalance_soc_error"),
        ({"spread_v_warn": 0.3}, "cells.spread_v_error"),  # warn above the default error
        ({"cell_voltage_min_v": 3.0, "cell_voltage_max_v": 2.5}, "cells.cell_voltage_max_v"),
        ({"soc_spread_std": 0.0}, "cells.soc_spread_std"),
    ):
        bad = copy.deepcopy(tree)
        bad["cells"] = change
        with pytest.raises(ParamFileError, match=named):
            parse_battery_params(bad)
    tree["cells"] = {"imbalance_soc_warn": 0.04, "cell_voltage_max_v": 3.65}
    params = parse_battery_params(tree)
    assert params.cells == CellSettings(imbalance_soc_warn=0.04, cell_voltage_max_v=3.65)
    dumped = battery_params_to_dict(params)
    assert dumped["cells"] == tree["cells"]
    assert parse_battery_params(dumped) == params


def test_rest_ocv_is_optional_and_round_trips() -> None:
    # The LFP file carries a rested OCV (soc_identify with a rate and a load test); without
    # the section the rested curve is the model's, to the bit.
    tree = base()
    params = parse_battery_params(tree)
    assert params.rest_ocv is not None
    assert params.rest_ocv != params.ocv
    curve = params.rest_ocv_curve()
    for soc, volts in zip(params.rest_ocv.soc, params.rest_ocv.voltage_v, strict=True):
        assert curve.ocv(soc) == pytest.approx(volts, abs=1e-12)  # PCHIP through its points
    again = parse_battery_params(battery_params_to_dict(params))
    assert again.rest_ocv == params.rest_ocv
    del tree["rest_ocv"]
    plain = parse_battery_params(tree)
    assert plain.rest_ocv is None
    for soc in (0.1, 0.23, 0.5, 0.9):
        assert plain.rest_ocv_curve().ocv(soc) == plain.ocv_curve().ocv(soc)


def _numbers(node, path=()):
    """Every numeric leaf of a YAML tree, as its path."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _numbers(v, (*path, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _numbers(v, (*path, i))
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        yield path


@pytest.mark.parametrize("path", BUNDLED, ids=lambda p: p.stem)
def test_a_file_that_loads_runs_every_estimator(path: Path) -> None:
    """A seeded fuzz of the bundled file (one or two numbers set to 0, a negative, a tiny, a
    huge or a scaled value): either the file is refused with its one-line ParamFileError, or
    an estimator is refused when built with its ValueError, or it runs: no other exception,
    every estimate a SoC in [0, 1] with a finite positive variance. Each bound of
    params.ABSURD and each tuning domain was found by this fuzz (NaN estimates, singular
    covariances, overflows, an unstable Saft model)."""
    import math
    import random

    from soc_estimator_ros.estimators import ESTIMATORS, make_estimator

    tree = yaml.safe_load(path.read_text())
    leaves = list(_numbers(tree))
    rng = random.Random(path.stem)
    loaded = 0
    for _ in range(300):
        mutant = copy.deepcopy(tree)
        for _ in range(rng.choice((1, 2))):
            *parents, last = rng.choice(leaves)
            node = mutant
            for k in parents:
                node = node[k]
            old = node[last]
            node[last] = rng.choice((0, -old, 1e-300, 1e-9, 1e9, 1e300, old * 1e3, old * 1e-3))
        try:
            battery = parse_battery_params(mutant, path.name)
        except ParamFileError as exc:
            assert "\n" not in str(exc)
            continue
        loaded += 1
        v_mid = 0.5 * (battery.limits.voltage_min_v + battery.limits.voltage_max_v)
        for name in ESTIMATORS:
            try:
                est = make_estimator(name, battery, 0.8, 0.1)
            except ValueError as exc:
                assert "\n" not in str(exc)
                continue
            for k in range(30):  # a 2 C burst every 7 s over a 0.5 C load
                current_a = battery.capacity_ah * (2.0 if k % 7 == 0 else 0.5)
                out = est.step(float(k), current_a, v_mid, 25.0)
                assert 0.0 <= out.soc <= 1.0, (name, mutant)
                assert 0.0 < out.soc_var and math.isfinite(out.soc_var), (name, mutant)
    assert loaded >= 30  # the draw ran the estimators on files that load, not only refusals
