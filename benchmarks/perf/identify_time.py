"""Wall time of identifying each bundled pulse test (alone, and with the rate and load tests at
its temperature, the way config/*.yaml were made at 25 degC), the whole of it as
``soc_identify`` does it (``identify_tests``: the fits, the surface lag, the model error).

Target (issue "Parameter identification"): <= 10 s per pulse test. Prints numbers, asserts
nothing. With ``--real-data DIR`` (default ``../shared/real-data`` when present) also the
Panasonic NCR18650PF HPPC tests (25 and 0 degC) behind config/li_ion_ncr18650pf.yaml.

    python benchmarks/perf/identify_time.py [--real-data DIR]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the checkout (its bags/ and config/)

from soc_estimator_ros.identification.cli import identify_tests  # noqa: E402
from soc_estimator_ros.params import load_battery_params  # noqa: E402
from soc_estimator_ros.recordings import read_battery_bag, read_recording  # noqa: E402


def identify_one(test, template, slow=None, rate_test=None, load_test=None):
    """One test at one temperature, as soc_identify identifies it; its result."""
    rates = None if rate_test is None else [rate_test]
    _, (res,) = identify_tests([test], None, template, None, slow, None, rates, load_test)
    return res


def timed(label: str, run) -> None:
    t0 = time.perf_counter()
    res = run()
    wall = time.perf_counter() - t0
    print(f"{label:<34} {len(res.pulses):>6} {wall:>8.1f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real-data", type=Path, default=ROOT.parent / "shared" / "real-data")
    args = ap.parse_args()
    print(f"{'test':<34} {'pulses':>6} {'wall_s':>8}")
    for chem, file in (("sla", "sla_12v5ah.yaml"), ("lfp", "lfp_12v6ah.yaml")):
        template = load_battery_params(ROOT / "config" / file)
        test = read_battery_bag(ROOT / "bags" / f"{chem}_pulse_test", reference_topic=None)
        slow = read_battery_bag(ROOT / "bags" / f"{chem}_slow_discharge", reference_topic=None)
        timed(
            f"{chem}_pulse_test + slow discharge",
            lambda t=test, tp=template, sl=slow: identify_one(t, tp, slow=sl),
        )
        # As the bundled file was made at 25 degC: with the rate test (and the load test).
        rate = read_battery_bag(ROOT / "bags" / f"{chem}_rate_test", reference_topic=None)
        load_bag = ROOT / "bags" / f"{chem}_load_test"
        load = read_battery_bag(load_bag, reference_topic=None) if load_bag.exists() else None
        timed(
            f"  + rate test{' + load test' if load is not None else ''}",
            lambda t=test, tp=template, sl=slow, r=rate, lt=load: identify_one(
                t, tp, slow=sl, rate_test=r, load_test=lt
            ),
        )
    hppc = args.real_data / "panasonic18650pf_25C_HPPC.csv"
    if hppc.is_file():
        template = load_battery_params(ROOT / "config" / "li_ion_ncr18650pf.yaml")
        for temp in ("25C", "0C"):
            path = args.real_data / f"panasonic18650pf_{temp}_HPPC.csv"
            test = replace(read_recording(path), reference_capacity_ah=2.9)
            timed(f"panasonic18650pf_{temp}_HPPC", lambda t=test, tp=template: identify_one(t, tp))
    else:
        print(f"(no real data in {args.real_data}: the HPPC tests are skipped)")
    print("(reading the inputs is not timed)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
