"""How accurate the model must be for the estimators' targets: the field runs with the model's
own voltage error scaled.

Each field run's voltage is replaced by

    v = v_exact + lam * (v_bag - v_exact),    v_exact = v_model(true SoC) + ADC noise,

where ``v_model`` is the battery file's Thevenin model run open loop on the bag's current with
its SoC set to the bag's reference at every sample (``simulate_voltage(..., gap_s=-1)``). At
``lam = 1`` that is the bag itself; at ``lam = 0`` a pack the model describes exactly, but for
the bags' ADC noise (2 mV white, bags/README.md); in between, the model's real error (its shape
in time, its dependence on load and SoC) at a fraction of its size. Everything else is the
bag's: the current with its sensor errors, the temperature, the reference. The printed RMSE is
that of ``v`` against ``v_model``: the model error the estimators see.

The estimators run from the true start and from 30 % below it (initial std 0.1, as in
``test/test_accuracy.py``); each line says which of the issue's targets it meets, as that test
checks them (MAE <= 1 %, max <= 3 %; from -30 %: within 2 % from 10 minutes on and MAE <= 1 %;
t2rc_ukf: MAE <= 1 % from the true start). With ``--tuning scaled`` the hybrid's model-error
terms follow lam (its defaults and the file's block at lam = 1, times: ``r`` lam^2, at least
(10 mV)^2; ``r_per_a`` lam; ``bias_std_v`` lam, at least 3 mV; the load up to which the
voltage updates 1 / lam, at most 100 C; the defaults are 0.05 V^2, 2 mV/A, 60 mV and 0.25 C,
the LFP file's block sets 0.1 V/A and 6 C): a filter tuned to its model's error; with
``--tuning file`` (default) the file's tuning at every lam. A diagnosis, not a test: the model
made exact along the truth uses the truth.

    python benchmarks/studies/model_error_budget.py [--config config/lfp_12v6ah.yaml]
        [--lambdas 0,0.25,0.5,1] [--estimators hybrid,t2rc_ukf] [--tuning file|scaled]
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import sys
from collections.abc import Mapping
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]  # the checkout (its bags/ and config/)

from soc_estimator_ros.estimators import make_estimator  # noqa: E402
from soc_estimator_ros.estimators.hybrid import Hybrid  # noqa: E402
from soc_estimator_ros.evaluation import accuracy, run_estimator  # noqa: E402
from soc_estimator_ros.identification.identify import simulate_voltage  # noqa: E402
from soc_estimator_ros.params import BatteryParams, load_battery_params  # noqa: E402
from soc_estimator_ros.recordings import BatterySeries, read_battery_bag  # noqa: E402

ADC_NOISE_V = 0.002  # bags/README.md: the voltage channel's white noise
INITIAL_SOC_STD = 0.1  # as test/test_accuracy.py
OFFSETS = (0.0, -0.3)


def model_voltage_on_truth(battery: BatteryParams, series: BatterySeries) -> np.ndarray:
    """The file's model voltage with its SoC held on the bag's reference at every sample."""
    if series.soc_ref is None:
        raise ValueError("the bag has no reference SoC")
    return simulate_voltage(battery, series, float(series.soc_ref[0]), series.soc_ref, gap_s=-1.0)


def scale_model_error(
    series: BatterySeries,
    model_v: np.ndarray,
    lam: float,
    noise_v: float = ADC_NOISE_V,
    seed: int = 1,
) -> BatterySeries:
    """``series`` with its voltage ``v_exact + lam (v - v_exact)``, v_exact = model + noise."""
    exact = model_v + np.random.default_rng(seed).normal(0.0, noise_v, model_v.size)
    return dataclasses.replace(series, voltage_v=exact + lam * (series.voltage_v - exact))


def scaled_hybrid_tuning(lam: float, base: Mapping[str, Any]) -> dict[str, Any]:
    """The hybrid's tuning ``base`` (its defaults with the file's block) for a model whose error
    is ``lam`` times the file's.

    The model-error terms scale with the error, down to floors (the ADC's noise and
    quantization, rounded up to 10 mV; a 3 mV bias); the load above which the voltage is not
    used (where the error under load outgrows the light-load one) with 1 / lam.
    """
    return {
        **base,
        "r": max(1.0e-4, base["r"] * lam**2),
        "r_per_a": base["r_per_a"] * lam,
        "bias_std_v": max(0.003, base["bias_std_v"] * lam),
        "update_c_rate_max": min(100.0, base["update_c_rate_max"] / max(lam, 1e-9)),
    }


@functools.lru_cache(maxsize=4)
def run_inputs(config: str, bag: str) -> tuple[BatteryParams, BatterySeries, np.ndarray]:
    """The file, the bag and the model on its truth: the same for every lam, estimator, start."""
    battery = load_battery_params(config)
    series = read_battery_bag(bag)
    return battery, series, model_voltage_on_truth(battery, series)


def job(args: tuple[str, str, str, float, float, str]) -> tuple:
    config, bag, estimator, lam, offset, tuning_mode = args
    battery, series, model_v = run_inputs(config, bag)
    scaled = scale_model_error(series, model_v, lam)
    rmse_mv = 1000.0 * float(np.sqrt(np.mean((scaled.voltage_v - model_v) ** 2)))
    tuning = None
    if tuning_mode == "scaled" and estimator == "hybrid":
        base = Hybrid.merged_tuning(battery.filters.get("hybrid"))
        tuning = scaled_hybrid_tuning(lam, base)
    soc0 = float(np.clip(series.soc_ref[0] + offset, 0.0, 1.0))
    est = make_estimator(estimator, battery, soc0, INITIAL_SOC_STD, tuning)
    out = run_estimator(est, scaled)
    acc = accuracy(out.t_s, out.soc, scaled.soc_ref)
    return Path(bag).name, estimator, lam, offset, rmse_mv, acc


def verdict(estimator: str, offset: float, acc) -> str:
    """The issue's targets this run meets ("ok") or misses (the bound it misses)."""
    if offset == 0.0:
        misses = []
        if acc.mae > 0.01:
            misses.append("MAE > 1 %")
        if estimator == "hybrid" and acc.max_abs > 0.03:
            misses.append("max > 3 %")
    else:
        if estimator != "hybrid":
            return "(no target)"
        # test_hybrid_converges_from_a_wrong_start: within 2 % from 10 minutes on, MAE <= 1 %.
        misses = [] if acc.max_abs < 0.02 else ["not within 2 % after 10 min"]
        if acc.mae > 0.01:
            misses.append("MAE > 1 %")
    return "ok" if not misses else ", ".join(misses)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, default=ROOT / "config" / "lfp_12v6ah.yaml")
    ap.add_argument("--bags", type=Path, default=ROOT / "bags")
    ap.add_argument("--lambdas", default="0,0.25,0.5,1")
    ap.add_argument("--estimators", default="hybrid,t2rc_ukf")
    ap.add_argument("--tuning", choices=("file", "scaled"), default="file")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    battery = load_battery_params(args.config)
    bags = sorted(str(p) for p in args.bags.glob(f"{battery.chemistry}_field_run*"))
    if not bags:
        print(f"no {battery.chemistry} field-run bags under {args.bags}")
        return 1
    lambdas = [float(v) for v in args.lambdas.split(",")]
    estimators = args.estimators.split(",")
    jobs = [
        (str(args.config), b, e, lam, off, args.tuning)
        for lam in lambdas
        for e in estimators
        for b in bags
        for off in OFFSETS
    ]
    print(f"{args.config.name}, tuning: {args.tuning}")
    met: dict[tuple[float, str], list[bool]] = {}
    rmse: dict[float, dict[str, float]] = {}
    with ProcessPoolExecutor(args.jobs) as ex:
        for bag, est, lam, off, rmse_mv, acc in ex.map(job, jobs):
            rmse.setdefault(lam, {})[bag] = rmse_mv
            word = verdict(est, off, acc)
            if word != "(no target)":
                met.setdefault((lam, est), []).append(word == "ok")
            conv = "never" if math.isinf(acc.t_converge_s) else f"{acc.t_converge_s:.0f} s"
            print(
                f"lam {lam:4.2f}  model RMSE {rmse_mv:6.1f} mV  {est:9} {bag:28} start {off:+.1f}: "
                f"MAE {100 * acc.mae:5.2f} %  max {100 * acc.max_abs:5.2f} %  "
                f"within 2 % after {conv:>6}  [{word}]",
                flush=True,
            )
    print("summary (model RMSE per run, in name order; runs and starts meeting all their targets):")
    for lam in lambdas:
        counts = ", ".join(
            f"{est} {sum(met[(lam, est)])} of {len(met[(lam, est)])}"
            for est in estimators
            if (lam, est) in met
        )
        errors = " / ".join(f"{rmse[lam][Path(b).name]:.0f}" for b in bags)
        print(f"  lam {lam:4.2f}: model RMSE {errors} mV; {counts}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
