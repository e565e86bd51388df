"""Make the bundled bags: seeder-robot runs and lab tests simulated by physics-based models.

Dev tool, not runtime: needs PyBaMM (``pip install .[sim]`` or ``tools/requirements-sim.txt``).
Never uses this package's equivalent-circuit models: the bags must measure the estimators, not
their agreement with themselves. Deterministic: the same seed gives the same bytes.

    python tools/make_bags.py                 # every bag into bags/
    python tools/make_bags.py --only sla_pulse_test --jobs 1
    python tools/make_bags.py --dev --out /tmp/missions   # the unbundled dev missions
    python tools/make_bags.py --graphite-diffusivity-x 10 --out /tmp/fast_graphite --only \
        lfp_pulse_test lfp_pulse_test_5c lfp_slow_discharge lfp_rate_test lfp_rate_test_5c \
        lfp_load_test lfp_field_run_1_full_rest lfp_field_run_2_partial lfp_field_run_3_cold
        # a dev pack, its graphite diffusing 10x faster (docs/identification.md)

Packs (bags/README.md): 12 V 5 Ah SLA = 6 cells of PyBaMM's full lead-acid model
(``lead_acid.Full``, Sulzer2019: 21.75 Ah at C/20) with the current scaled by 21.75/5;
12 V 6 Ah LFP =
4 cells of PyBaMM's SPMe with Prada2013 (A123 26650, 2.3 Ah) with the current scaled by 2.3/6.

Simulator traps found and avoided (checked on every bag before it is written):
* the current must not be a sharp ``Interpolant``: IDAKLU steps over a 1 ms step and the
  lead-acid voltage stays frozen at 17 A. Each constant-current segment is a separate
  ``Simulation.step`` with the current as an input, so the solver restarts and re-initializes
  its algebraic states at every step (the voltage answers in the same sample);
* the leading-order lead-acid model (LOQS) freezes after pulses above about 0.4C: the full
  model is used;
* a solution is sampled by time (``t_eval`` at the sample stamps), never by solver step.
"""

from __future__ import annotations

import argparse
import math
import shutil
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]

from soc_estimator_ros.messages import TECHNOLOGY_BY_CHEMISTRY as TECH  # noqa: E402
from soc_estimator_ros.messages import bridge_state  # noqa: E402
from soc_estimator_ros.recordings import (  # noqa: E402
    REFERENCE_TOPIC,
    STATE_TOPIC,
    battery_state_message,
    write_battery_bag,
)

EPOCH_NS = 1_777_881_600 * 1_000_000_000  # 2026-05-04 08:00:00 UTC, fixed for determinism
SAMPLE_S = 0.1  # the bridge's 10 Hz


@dataclass(frozen=True)
class Pack:
    """A pack of identical cells in series, simulated as one cell times ``cells``."""

    chemistry: str
    cells: int
    cell_capacity_ah: float
    pack_capacity_ah: float  # nominal, for scaling the current
    cutoff_v: float  # manufacturer's end-of-discharge, pack level
    soc_limit: float  # lowest SoC a run goes to
    technology: int
    serial: str
    #: Dev only (``--graphite-diffusivity-x``): the LFP cell's graphite particle diffusivity
    #: times this, to see what the graphite's slow diffusion does to the identified model.
    graphite_diffusivity_x: float = 1.0

    @property
    def current_scale(self) -> float:
        """Cell current per pack ampere."""
        return self.cell_capacity_ah / self.pack_capacity_ah


PACKS = {
    # Sulzer2019's "17 Ah" cell delivers 21.75 Ah at C/20 to 1.75 V; SLA packs are rated at
    # C/20, so the current is scaled by 21.75/5 to make the pack a 5 Ah (C/20) pack.
    "sla": Pack("sla", 6, 21.75, 5.0, 10.5, 0.40, TECH["sla"], "AJC-12V5AH-SIM"),
    "lfp": Pack("lfp", 4, 2.3, 6.0, 10.0, 0.20, TECH["lfp"], "ROYPOW-12V6AH-SIM"),
}


class PackSim:
    """One pack in PyBaMM, stepped segment by segment at constant current."""

    def __init__(self, pack: Pack, temp_c: float) -> None:
        import pybamm

        pybamm.set_logging_level("ERROR")
        self.pack = pack
        if pack.chemistry == "sla":
            model = pybamm.lead_acid.Full()
            pv = pybamm.ParameterValues("Sulzer2019")
            pv["Initial State of Charge"] = 1.0
            # Events on the cell voltage; the pack's own cut-off is applied by this tool.
            pv["Upper voltage cut-off [V]"] = 2.7
            pv["Lower voltage cut-off [V]"] = 1.5
        else:
            model = pybamm.lithium_ion.SPMe()
            pv = pybamm.ParameterValues("Prada2013")
            if pack.graphite_diffusivity_x != 1.0:
                key = "Negative particle diffusivity [m2.s-1]"
                pv[key] = pv[key] * pack.graphite_diffusivity_x
            pv["Lower voltage cut-off [V]"] = 2.0
            pv = pv.set_initial_state(1.0, inplace=False)  # 100 %: OCV at the 3.6 V limit
            # Solver events only (set after the initial state, which uses 2.0-3.6 V): a cold
            # pack sags below 2.0 V/cell on a 38 A peak; the pack cut-off is this tool's job.
            pv["Upper voltage cut-off [V]"] = 3.8
            pv["Lower voltage cut-off [V]"] = 1.5
        pv["Ambient temperature [K]"] = 273.15 + temp_c
        pv["Initial temperature [K]"] = 273.15 + temp_c
        pv["Current function [A]"] = "[input]"
        self.temp_c = temp_c
        self.sim = pybamm.Simulation(
            model, parameter_values=pv, solver=pybamm.IDAKLUSolver(rtol=1e-6, atol=1e-8)
        )
        self.t_s = 0.0
        self.discharged_ah = 0.0
        self.last_v = math.nan

    def segment(
        self, duration_s: float, current_a: float, sample_times: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Hold ``current_a`` (pack, discharge +) for ``duration_s``; sample the voltage and
        the discharged charge at ``sample_times`` (absolute, within [t, t + duration))."""
        rel = np.clip(np.round(sample_times - self.t_s, 9), 0.0, duration_s)
        t_eval = np.unique(np.concatenate([[0.0], rel, [duration_s]]))
        sol = self.sim.step(
            dt=duration_s,
            t_eval=t_eval,
            inputs={"Current function [A]": current_a * self.pack.current_scale},
            save=False,
        )
        last = sol.sub_solutions[-1] if hasattr(sol, "sub_solutions") else sol
        t_rel = last.t - last.t[0]
        if abs(t_rel[-1] - duration_s) > 1e-6:
            raise RuntimeError(
                f"{self.pack.chemistry}: solver stopped at {t_rel[-1]:.1f} of {duration_s:.1f} s"
            )
        v = last["Voltage [V]"].entries * self.pack.cells
        q = last["Discharge capacity [A.h]"].entries / self.pack.current_scale
        v_s = np.interp(rel, t_rel, v)
        q_s = np.interp(rel, t_rel, q)
        self.t_s += duration_s
        self.discharged_ah = float(q[-1])
        self.last_v = float(v[-1])
        return v_s, q_s


@dataclass
class Recording:
    """True signals at the sample stamps (pack level, discharge +)."""

    t_s: list[np.ndarray] = field(default_factory=list)
    current_a: list[np.ndarray] = field(default_factory=list)
    voltage_v: list[np.ndarray] = field(default_factory=list)
    discharged_ah: list[np.ndarray] = field(default_factory=list)

    def add(self, t, i, v, q) -> None:
        self.t_s.append(t)
        self.current_a.append(np.full(t.size, float(i)))
        self.voltage_v.append(v)
        self.discharged_ah.append(q)

    def arrays(self):
        return tuple(
            np.concatenate(x)
            for x in (self.t_s, self.current_a, self.voltage_v, self.discharged_ah)
        )


def run_segments(sim: PackSim, segments, rec: Recording | None, rate_hz=10.0, tail_rate_hz=None):
    """Simulate ``(duration_s, current_a)`` segments; record samples when ``rec`` is given.

    With ``tail_rate_hz``, a segment's samples after its first 300 s are logged at that
    slower rate (long rests of lab tests).
    """
    for duration, current in segments:
        t0 = sim.t_s
        if rec is None:
            sim.segment(duration, current, np.array([], dtype=float))
            continue
        n = int(round(duration * rate_hz))
        times = t0 + np.arange(n) / rate_hz
        if tail_rate_hz is not None and duration > 300.0:
            keep = (times - t0 < 300.0) | (
                np.isclose(((times - t0) * tail_rate_hz) % 1.0, 0.0, atol=1e-6)
            )
            times = times[keep]
        times = np.round(times, 6)
        v, q = sim.segment(duration, current, times)
        rec.add(times, current, v, q)


# -- profiles -------------------------------------------------------------------------------
def step_segments(current_a: float, step_s: float, n_steps: int) -> list[tuple[float, float]]:
    """A 10-min rest, then ``n_steps`` steps of ``current_a`` for ``step_s`` with 1-h rests."""
    segs = [(600.0, 0.0)]
    for _ in range(n_steps):
        segs += [(step_s, current_a), (3600.0, 0.0)]
    return segs


def pulse_test_segments(pack: Pack) -> list[tuple[float, float]]:
    """Seed 000 §2.1: rest, then 30-min pulses of ~10 % SoC each with 1-h rests."""
    current = 0.2 * pack.pack_capacity_ah  # 10 % in 30 min (the paper's 13.5 / 12 ohm loads)
    n_pulses = 6 if pack.chemistry == "sla" else 8  # to 40 % (SLA) and 20 % (LFP)
    return step_segments(current, 1800.0, n_pulses)


#: Rate test pulse currents, in C (pack capacity per hour): the field runs' 0.1-7 C span.
RATE_TEST_C = (0.1, 0.2, 0.5, 1.0, 2.0, 3.0, 4.0, 6.0)


def rate_test_segments(pack: Pack) -> list[tuple[float, float]]:
    """An HPPC-style rate test: at each SoC level (after a 1-h rest), one 5-s discharge pulse
    per rate of :data:`RATE_TEST_C` with 40-s rests, then 30 min at 0.2 C to the next level.

    The pulses remove 2.4 % of the charge per level; five levels (SLA, 100 % to 39 %) or seven
    (LFP, 100 % to 14 %). The instantaneous voltage drop against the pulse current is what the
    2RC model's constant R0 cannot follow (Butler-Volmer kinetics): the identification's
    ``--rate-test`` fits it.
    """
    c = pack.pack_capacity_ah
    n_levels = 5 if pack.chemistry == "sla" else 7
    segs = [(600.0, 0.0)]
    for level in range(n_levels):
        if level:
            segs += [(3600.0, 0.0)]
        for rate in RATE_TEST_C:
            segs += [(5.0, rate * c), (40.0, 0.0)]
        segs += [(1800.0, 0.2 * c)]
    return segs + [(3600.0, 0.0)]


#: Load test: the field runs' heavy load (the seeder uphill, ~18 A on the LFP pack), in C.
LOAD_TEST_C = 3.0


def load_test_segments(pack: Pack) -> list[tuple[float, float]]:
    """A load test: the pulse test's 10 % steps with 1-h rests, each taken at the field runs'
    heavy load (:data:`LOAD_TEST_C`, 2 min) instead of 0.2 C (30 min).

    The slow recovery after a heavy load (the particles' diffusion, minutes) is what neither the
    0.2 C pulse test nor the rate test's 5-s pulses excite; ``soc_identify --load-test`` fits
    the surface lag's modes on it.
    """
    # To 30 % (LFP, the only pack with one: at 3 C the cell collapses through the solver's 1.5 V
    # event near 22 %, its particles' surface full).
    return step_segments(LOAD_TEST_C * pack.pack_capacity_ah, 0.1 * 3600.0 / LOAD_TEST_C, 7)


def mission(rng: np.random.Generator, pack: Pack):
    """Endless seeded seeder-robot mission: yields (duration_s, pack current A) segments.

    Two drive motors (seed 000 Table 2: Ampflow E30-150, 514 W peak), electronics always on,
    seeder linear actuators, flat and sloped ground forward and backward, idle stops.
    """
    electronics = 0.35
    while True:
        activity = rng.choice(
            ["forward", "backward", "uphill", "downhill", "turn", "idle"],
            p=[0.30, 0.12, 0.10, 0.10, 0.08, 0.30],
        )
        if activity == "idle":  # seeding stops, operator checks: electronics only
            yield float(rng.uniform(30, 240)), electronics
            continue
        duration = {
            "forward": (20, 80),
            "backward": (8, 30),
            "uphill": (10, 40),
            "downhill": (10, 40),
            "turn": (3, 8),
        }[activity]
        mean, spread = {
            "forward": (6.0, 1.5),
            "backward": (5.5, 1.5),
            "uphill": (18.0, 4.0),
            "downhill": (2.0, 1.0),
            "turn": (11.0, 2.5),
        }[activity]
        remaining = float(rng.uniform(*duration))
        # Start-up transient of the motor controllers.
        yield 1.0, electronics + min(1.5 * mean, 38.0)
        while remaining > 0.0:
            seg = float(min(rng.uniform(1.0, 4.0), remaining))
            remaining -= seg
            level = float(np.clip(rng.normal(mean, spread), 0.5, 38.0))
            if activity == "downhill" and rng.random() < 0.3:
                level = -float(rng.uniform(1.0, 4.0))  # regenerative braking
            if activity == "forward" and rng.random() < 0.15:
                yield seg, electronics + level + 3.0  # seeder actuators extend
                continue
            yield seg, electronics + level


def quantize(x: np.ndarray, step: float) -> np.ndarray:
    return np.round(x / step) * step


@dataclass(frozen=True)
class SensorModel:
    """Low-cost sensors as on the robot (seed 000: LEM CAS 25-NP; seed 001: ACS712)."""

    current_gain: float
    current_offset_a: float
    current_noise_a: float = 0.04
    current_step_a: float = 0.04
    voltage_gain: float = 0.0
    voltage_noise_v: float = 0.002
    voltage_step_v: float = 16.0 / 4096.0
    temperature_noise_c: float = 0.3
    temperature_step_c: float = 0.1

    @classmethod
    def draw(cls, rng: np.random.Generator) -> SensorModel:
        return cls(
            current_gain=float(rng.uniform(-0.008, 0.008)),
            current_offset_a=float(rng.uniform(-0.03, 0.03)),
            voltage_gain=float(rng.uniform(-5e-4, 5e-4)),
        )

    def measure(self, rng, current_a, voltage_v, temperature_c):
        i = current_a * (1.0 + self.current_gain) + self.current_offset_a
        i = quantize(i + rng.normal(0.0, self.current_noise_a, i.size), self.current_step_a)
        v = voltage_v * (1.0 + self.voltage_gain) + rng.normal(0.0, self.voltage_noise_v, i.size)
        v = quantize(v, self.voltage_step_v)
        t = quantize(
            temperature_c + rng.normal(0.0, self.temperature_noise_c, i.size),
            self.temperature_step_c,
        )
        return i, v, t

    def as_dict(self) -> dict[str, float]:
        return {k: round(float(v), 6) for k, v in self.__dict__.items()}


# -- checks ---------------------------------------------------------------------------------
def check_recording(name: str, t, i, v, soc, capacity_ah, rest_ends: list[int] | None) -> None:
    """Refuse to write a bag whose simulated signals are not physical (module docstring)."""
    if not np.all(np.diff(t) > 0):
        raise RuntimeError(f"{name}: stamps not strictly increasing")
    di = np.diff(i)
    dv = np.diff(v)
    steps = np.flatnonzero(np.abs(di) > 0.2)  # the smallest designed step: C/20 (0.25 A)
    # Every current step moves the voltage in the same sample, the opposite way.
    bad = [k for k in steps if not (dv[k] * di[k] < 0 and abs(dv[k]) > 0.002 * abs(di[k]))]
    if bad:
        k = bad[0]
        raise RuntimeError(
            f"{name}: {len(bad)} of {steps.size} current steps do not move the voltage in the "
            f"same sample (first at t={t[k + 1]:.1f} s: dI={di[k]:+.2f} A, dV={dv[k]:+.4f} V)"
        )
    loaded = np.abs(i[1:]) > 1.0
    frozen = loaded & (np.abs(dv) == 0.0)
    if np.mean(frozen[loaded]) > 0.5 if loaded.any() else False:
        raise RuntimeError(f"{name}: voltage frozen under load")
    # The reference SoC is the integral of the true current (zero-order hold).
    dt = np.diff(t)
    expected = soc[0] - np.concatenate([[0.0], np.cumsum(i[:-1] * dt)]) / 3600.0 / capacity_ah
    err = np.max(np.abs(expected - soc))
    if err > 2e-4:  # solver tolerance on the charge (rtol 1e-6) over hours, far below 0.1 %
        raise RuntimeError(f"{name}: reference SoC departs from the current integral by {err:.2e}")
    if rest_ends:
        rest_v = v[rest_ends]
        if not np.all(np.diff(rest_v) < 0):
            raise RuntimeError(f"{name}: rest voltages do not fall with SoC: {rest_v}")


# -- bags -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class BagSpec:
    name: str
    chemistry: str
    kind: str  # pulse_test | rate_test | load_test | slow_discharge | field_run
    seed: int
    temp_c: float = 25.0
    start_soc: float = 1.0
    long_rest_s: float = 0.0
    storage: str = "mcap"
    description: str = ""


SPECS = [
    BagSpec(
        "sla_pulse_test",
        "sla",
        "pulse_test",
        11,
        description="Seed 000 §2.1 pulse-discharge test: 10 min rest, six 30-min 1.0 A "
        "pulses (10 % SoC each) with 1-h rests, 100 % to 40 %.",
    ),
    BagSpec(
        "sla_slow_discharge",
        "sla",
        "slow_discharge",
        12,
        description="C/20 (0.25 A) discharge from full to 10.5 V, for the OCV curve.",
    ),
    BagSpec(
        "sla_field_run_1_full_rest",
        "sla",
        "field_run",
        13,
        long_rest_s=2100.0,
        description="Seeder mission from full to 40 %, with a 35-min stop (robot off, "
        "bridge logging) half-way.",
    ),
    BagSpec(
        "sla_field_run_2_partial",
        "sla",
        "field_run",
        14,
        start_soc=0.8,
        storage="sqlite3",
        description="Seeder mission starting part-charged (80 %, after a 2-h rest) down to 40 %.",
    ),
    BagSpec(
        "sla_field_run_3_cold",
        "sla",
        "field_run",
        15,
        temp_c=5.0,
        description="Seeder mission from full to 40 % at 5 degC ambient.",
    ),
    BagSpec(
        "lfp_pulse_test",
        "lfp",
        "pulse_test",
        21,
        description="Seed 000 §2.1 pulse-discharge test: 10 min rest, eight 30-min 1.2 A "
        "pulses (10 % SoC each) with 1-h rests, 100 % to 20 %.",
    ),
    BagSpec(
        "lfp_slow_discharge",
        "lfp",
        "slow_discharge",
        22,
        description="C/20 (0.3 A) discharge from full to 10.0 V, for the OCV curve.",
    ),
    BagSpec(
        "lfp_field_run_1_full_rest",
        "lfp",
        "field_run",
        23,
        long_rest_s=2100.0,
        description="Seeder mission from full to 20 %, with a 35-min stop (robot off, "
        "bridge logging) half-way.",
    ),
    BagSpec(
        "lfp_field_run_2_partial",
        "lfp",
        "field_run",
        24,
        start_soc=0.8,
        storage="sqlite3",
        description="Seeder mission starting part-charged (80 %, after a 2-h rest) down to 20 %.",
    ),
    BagSpec(
        "lfp_field_run_3_cold",
        "lfp",
        "field_run",
        25,
        temp_c=5.0,
        description="Seeder mission from full to 20 % at 5 degC ambient.",
    ),
    # Appended (the stamps of a bag depend on its index here): rate tests and cold tests.
    BagSpec(
        "sla_rate_test",
        "sla",
        "rate_test",
        16,
        description="Rate test: at five SoC levels (100 % to 51 %, 1-h rests), 5-s pulses at "
        "0.1, 0.2, 0.5, 1, 2, 3, 4 and 6 C (0.5-30 A) with 40-s rests; 30 min at 0.2 C between "
        "levels.",
    ),
    BagSpec(
        "lfp_rate_test",
        "lfp",
        "rate_test",
        26,
        description="Rate test: at seven SoC levels (100 % to 26 %, 1-h rests), 5-s pulses at "
        "0.1, 0.2, 0.5, 1, 2, 3, 4 and 6 C (0.6-36 A) with 40-s rests; 30 min at 0.2 C between "
        "levels.",
    ),
    BagSpec(
        "sla_pulse_test_5c",
        "sla",
        "pulse_test",
        17,
        temp_c=5.0,
        description="The pulse test of sla_pulse_test at 5 degC ambient.",
    ),
    BagSpec(
        "lfp_pulse_test_5c",
        "lfp",
        "pulse_test",
        27,
        temp_c=5.0,
        description="The pulse test of lfp_pulse_test at 5 degC ambient.",
    ),
    BagSpec(
        "sla_rate_test_5c",
        "sla",
        "rate_test",
        18,
        temp_c=5.0,
        description="The rate test of sla_rate_test at 5 degC ambient.",
    ),
    BagSpec(
        "lfp_rate_test_5c",
        "lfp",
        "rate_test",
        28,
        temp_c=5.0,
        description="The rate test of lfp_rate_test at 5 degC ambient.",
    ),
    BagSpec(
        "lfp_load_test",
        "lfp",
        "load_test",
        29,
        description="Load test: 10 min rest, seven 10 % steps at 3 C (18 A for 2 min) with 1-h "
        "rests, 100 % to 30 %.",
    ),
]

#: Not bundled (``--dev``, into a directory of your own): seeder missions from full to 20 %
#: with seeds apart from the field runs', on which ``benchmarks/studies/table_transfer.py`` fits the
#: 2RC's tables to see whether they carry over to the field runs (docs/identification.md).
DEV_SPECS = [
    BagSpec(
        f"lfp_mission_{seed}",
        "lfp",
        "field_run",
        seed,
        description=f"Seeder mission from full to 20 % (seed {seed}; a dev bag, not bundled).",
    )
    for seed in (32, 34, 35, 36, 37, 38)
]


def slow_discharge(pack: Pack, rec: Recording | None) -> float:
    """C/20 from the full state (after a 10-min rest) to the pack cut-off, at 25 degC.

    Returns the charge delivered at the cut-off crossing (interpolated between 1-s samples):
    the reference capacity of every bag of this pack. Samples past the crossing are dropped.
    """
    sim = PackSim(pack, 25.0)
    run_segments(sim, [(600.0, 0.0)], rec, rate_hz=1.0)
    current = pack.pack_capacity_ah / 20.0
    local = Recording()
    while True:
        run_segments(sim, [(600.0, current)], local, rate_hz=1.0)
        v, q = local.voltage_v[-1], local.discharged_ah[-1]
        below = np.flatnonzero(v <= pack.cutoff_v)
        if below.size:
            k = int(below[0])
            if rec is not None:
                for j in range(len(local.t_s)):
                    cut = k + 1 if j == len(local.t_s) - 1 else local.t_s[j].size
                    rec.add(
                        local.t_s[j][:cut],
                        current,
                        local.voltage_v[j][:cut],
                        local.discharged_ah[j][:cut],
                    )
            w = (v[k - 1] - pack.cutoff_v) / (v[k - 1] - v[k])
            return float(q[k - 1] + w * (q[k] - q[k - 1]))


def reference_capacity_ah(pack: Pack) -> float:
    """The pack's reference capacity (see :func:`slow_discharge`)."""
    return slow_discharge(pack, None)


def simulate_bag(spec: BagSpec, capacity_ah: float, pack: Pack) -> dict:
    rng = np.random.default_rng(spec.seed)
    sim = PackSim(pack, spec.temp_c)
    rec = Recording()
    rest_ends: list[int] | None = None
    soc = lambda: 1.0 - sim.discharged_ah / capacity_ah  # noqa: E731
    if spec.kind in ("pulse_test", "load_test"):
        segs = (pulse_test_segments if spec.kind == "pulse_test" else load_test_segments)(pack)
        run_segments(sim, segs, rec, tail_rate_hz=1.0)
        counts = np.cumsum([x.size for x in rec.t_s])
        rest_ends = [int(counts[0]) - 1] + [int(counts[k]) - 1 for k in range(2, len(segs), 2)]
    elif spec.kind == "rate_test":
        segs = rate_test_segments(pack)
        run_segments(sim, segs, rec, tail_rate_hz=1.0)
        counts = np.cumsum([x.size for x in rec.t_s])
        rest_ends = [
            int(counts[k]) - 1 for k, (dur, cur) in enumerate(segs) if dur >= 600.0 and cur == 0.0
        ]
    elif spec.kind == "slow_discharge":
        slow_discharge(pack, rec)
    else:
        if spec.start_soc < 1.0:  # unrecorded: use the pack down to start_soc, then park 2 h
            while soc() > spec.start_soc:
                run_segments(sim, [(30.0, pack.pack_capacity_ah / 5.0)], None)
            run_segments(sim, [(7200.0, 0.0)], None)
        missions = mission(rng, pack)
        start_soc = soc()
        half = start_soc - 0.5 * (start_soc - pack.soc_limit)
        rested = spec.long_rest_s <= 0.0
        while soc() > pack.soc_limit:
            duration, current = next(missions)
            duration = round(duration, 1)
            if duration >= SAMPLE_S:
                run_segments(sim, [(duration, current)], rec)
            if not rested and soc() <= half:
                run_segments(sim, [(spec.long_rest_s, 0.05)], rec)  # robot off, bridge on
                rested = True
    t, i, v, q = rec.arrays()
    soc_ref = 1.0 - q / capacity_ah
    check_recording(spec.name, t, i, v, soc_ref, capacity_ah, rest_ends)
    return {"t": t, "i": i, "v": v, "soc": soc_ref, "temp_c": spec.temp_c}


#: MCAP bags: zstd chunks inside a plain .mcap (Foxglove and PlotJuggler open it as is);
#: sqlite3 has no chunks, its bags stay rosbag2 file-compressed (.db3.zstd).
COMPRESSION = {"mcap": "chunk", "sqlite3": "file"}
COMPRESSION_TEXT = {"mcap": "zstd-compressed MCAP chunks", "sqlite3": "zstd file compression"}


def write_bag(spec: BagSpec, data: dict, capacity_ah: float, out_dir: Path, pack: Pack) -> dict:
    rng = np.random.default_rng(spec.seed + 1000)
    sensors = SensorModel.draw(rng)
    t, i, v, soc = data["t"], data["i"], data["v"], data["soc"]
    temp = np.full(t.size, data["temp_c"])
    i_m, v_m, temp_m = sensors.measure(rng, i, v, temp)
    start_ns = EPOCH_NS + (SPECS + DEV_SPECS).index(spec) * 86_400 * 1_000_000_000
    stamps = start_ns + np.round(t * 1e9).astype(np.int64)
    state = (
        battery_state_message(
            bridge_state(
                int(s),
                float(vm),
                float(im),
                temperature_c=float(tm),
                design_capacity_ah=pack.pack_capacity_ah,
                technology=pack.technology,
                location="seeder_robot",
                serial_number=pack.serial,
            )
        )
        for s, vm, im, tm in zip(stamps, v_m, i_m, temp_m, strict=True)
    )
    reference = (
        battery_state_message(
            bridge_state(
                int(s),
                float(vt),
                float(it),
                temperature_c=float(tt),
                percentage=float(sc),
                charge_ah=float(sc * capacity_ah),
                capacity_ah=capacity_ah,
                design_capacity_ah=pack.pack_capacity_ah,
                technology=pack.technology,
                location="simulator_truth",
                serial_number=pack.serial,
            )
        )
        for s, vt, it, tt, sc in zip(stamps, v, i, temp, soc, strict=True)
    )
    bag = out_dir / spec.name
    if bag.exists():
        shutil.rmtree(bag)
    write_battery_bag(
        bag,
        [(STATE_TOPIC, state), (REFERENCE_TOPIC, reference)],
        storage=spec.storage,
        compression=COMPRESSION[spec.storage],
    )
    dt = np.diff(t)
    meta = {
        "name": spec.name,
        "chemistry": spec.chemistry,
        "kind": spec.kind,
        "storage": spec.storage,
        "seed": spec.seed,
        "ambient_temperature_c": spec.temp_c,
        "duration_s": round(float(t[-1] - t[0]), 1),
        "samples": int(t.size),
        "sample_rate_hz": round(float(1.0 / np.median(dt)), 3),
        "soc_start": round(float(soc[0]), 4),
        "soc_end": round(float(soc[-1]), 4),
        "reference_capacity_ah": round(capacity_ah, 4),
        "current_max_a": round(float(np.max(i)), 2),
        "current_min_a": round(float(np.min(i)), 2),
        "sensors": sensors.as_dict(),
        "description": spec.description,
    }
    if pack.graphite_diffusivity_x != 1.0:
        meta["description"] += (
            f" Dev pack: the graphite's diffusivity x{pack.graphite_diffusivity_x:g}."
        )
    (bag / "bag.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    (bag / "README.md").write_text(bag_readme(meta))
    return meta


def bag_readme(meta: dict) -> str:
    s = meta["sensors"]
    return f"""# {meta["name"]}

{meta["description"]}

- Chemistry: {meta["chemistry"]} (see ../README.md for the pack model and scaling);
  ambient {meta["ambient_temperature_c"]} degC.
- Duration {meta["duration_s"] / 3600.0:.2f} h, {meta["samples"]} samples at
  {meta["sample_rate_hz"]} Hz (median rate); SoC {meta["soc_start"]:.3f} -> {meta["soc_end"]:.3f}
  (reference capacity {meta["reference_capacity_ah"]} Ah); current
  {meta["current_min_a"]} .. {meta["current_max_a"]} A (discharge positive).
- Sensors: current gain error {s["current_gain"]:+.4f}, offset {s["current_offset_a"]:+.3f} A,
  noise {s["current_noise_a"]} A, quantized to {s["current_step_a"]} A; voltage gain error
  {s["voltage_gain"]:+.5f}, noise {s["voltage_noise_v"] * 1000:.1f} mV, 12-bit ADC over 16 V
  ({s["voltage_step_v"] * 1000:.2f} mV steps); temperature noise {s["temperature_noise_c"]} degC.
- Storage: rosbag2 {meta["storage"]}, {COMPRESSION_TEXT[meta["storage"]]}. Seed {meta["seed"]}.
- `/battery/soc_reference` is the simulator's true SoC, not a measurement.
"""


def build(spec: BagSpec, capacity_ah: float, out_dir: str, pack: Pack) -> dict:
    data = simulate_bag(spec, capacity_ah, pack)
    return write_bag(spec, data, capacity_ah, Path(out_dir), pack)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Simulate the bundled bags with PyBaMM.")
    ap.add_argument("--out", type=Path, default=ROOT / "bags")
    ap.add_argument("--only", nargs="*", help="bag names to (re)make")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument(
        "--dev", action="store_true", help="make the dev missions (DEV_SPECS), not the bundled bags"
    )
    ap.add_argument(
        "--graphite-diffusivity-x",
        type=float,
        default=1.0,
        help="dev: the LFP cell's graphite diffusivity times this (not for bags/)",
    )
    args = ap.parse_args(argv)
    dev = args.dev or args.graphite_diffusivity_x != 1.0
    if dev and args.out.resolve() == (ROOT / "bags").resolve():
        ap.error("dev bags are not bundled: give --out a directory outside bags/")
    packs = dict(PACKS)
    packs["lfp"] = replace(packs["lfp"], graphite_diffusivity_x=args.graphite_diffusivity_x)
    pool_specs = DEV_SPECS if args.dev else SPECS
    specs = [s for s in pool_specs if not args.only or s.name in args.only]
    chems = sorted({s.chemistry for s in specs})  # the capacities only of the packs made
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        caps = dict(
            zip(chems, pool.map(reference_capacity_ah, [packs[c] for c in chems]), strict=True)
        )
        for chem, cap in caps.items():
            print(f"{chem}: reference capacity {cap:.4f} Ah (C/20 to cut-off, 25 degC)")
        futures = [
            pool.submit(build, s, caps[s.chemistry], str(args.out), packs[s.chemistry])
            for s in specs
        ]
        for fut in futures:
            m = fut.result()
            print(
                f"{m['name']}: {m['duration_s'] / 3600:.2f} h, SoC {m['soc_start']:.3f} -> "
                f"{m['soc_end']:.3f}, {m['samples']} samples"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
