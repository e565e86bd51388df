"""Make the bundled bags: seeder-robot runs and lab tests simulated by physics-based models.

Dev tool, not runtime: needs PyBaMM (``pip install .[sim]`` or ``tools/requirements-sim.txt``).
Never uses this package's equivalent-circuit models: the bags must measure the estimators, not
their agreement with themselves. Deterministic: the same seed gives the same bytes.

    python tools/make_bags.py                 # every bag into bags/
    python tools/make_bags.py --only sla_pulse_test --jobs 1
    python tools/make_bags.py --dev --out /tmp/missions   # the unbundled dev missions
    python tools/make_bags.py --dev --only li_ion4s_pulse_test_5c --out dev_bags   # its 5 degC
    python tools/make_bags.py --graphite-diffusivity-x 10 --out /tmp/fast_graphite --only \
        lfp_pulse_test lfp_pulse_test_5c lfp_slow_discharge lfp_rate_test lfp_rate_test_5c \
        lfp_load_test lfp_field_run_1_full_rest lfp_field_run_2_partial lfp_field_run_3_cold
        # a dev pack, its graphite diffusing 10x faster (docs/identification.md)
    python tools/make_bags.py --corpus --out /work/corpus [--count 30] [--chemistry lfp sla] \
        [--seeds 1001 1003] [--jobs 1]   # the scenario corpus (below), outside the repo
    python tools/make_bags.py --aged --out /work/health_corpus [--chemistry lfp sla] \
        [--only lfp_aged75] --jobs 1     # battery health: fresh and aged packs' missions
    python tools/make_bags.py --sized --out /work/health_corpus --jobs 1   # 24 V packs
    python tools/make_bags.py --cells --out bags --jobs 2   # 4S LFP packs cell by cell
    python tools/make_bags.py --cells [--chemistry li_ion] --seeds 60 61 ... --out DIR \
        --jobs 2   # the cell-by-cell validation corpus (not bundled)
    python tools/make_bags.py --hysteresis --out /work/hyst_bags --jobs 1   # hysteretic LFP
    python tools/make_bags.py --hysteresis --out bags --jobs 1   # its bundled test only

OCV hysteresis (``--hysteresis``; bags/README.md, "Hysteresis"): the LFP pack with PyBaMM's
one-state OCP hysteresis on its LFP electrode (:data:`HYSTERESIS_PACK`, ``Pack.ocp_hysteresis_v``:
16 mV per cell between the charge and discharge branches, the branch change's e-folding charge
2 % of the capacity), the state keeping its branch at rest. A two-direction pulse test
(``lfp_hysteresis_test``, :func:`hysteresis_test_segments`) and three seeder missions
(:data:`HYSTERESIS_MISSIONS`: a dock charge, an opportunity charge on the plateau, a cold one).

Series packs cell by cell (``--cells``; bags/README.md, "Series packs cell by cell"): each cell
of a 4S LFP pack is its own PyBaMM simulation carrying the pack current, with a cell-to-cell
spread of capacity, resistance and initial SoC (:data:`CELLS_SPECS`, :func:`simulate_cells`);
the cell voltages go through a per-cell ADC into ``cell_voltage``.

Battery health (``--aged``, ``--sized``; bags/README.md, "Aged packs and packs of other
sizes"): each pack of :data:`HEALTH_PACKS` (LFP aged by loss of lithium inventory and active
material, SLA by loss of active plate area, both with a series resistance; fresh packs as the
control; 24 V packs of other sizes) is measured (C/20 capacity, 5-s resistance, kept in
``DIR/packs.yaml``) and given 2-3 missions from full with a rest half-way and at the end, 2 Hz,
seeds from 2000 (validation, but for the ``*_tuning`` packs); ``DIR/STATUS.md`` lists the packs
and the missions written.

Scenario corpus (``--corpus``; bags/README.md, "Scenario corpus", has the full table): seeded
missions, one bag per mission in the bundled bags' format (``kind: mission``), with ``split``,
``seed`` and every drawn value in bag.yaml. Seeds count from 1000 per chemistry (the chemistry
is a second word of each random stream); **odd seeds are validation, even seeds tuning**.
Per mission (:func:`draw_scenario`):

* profile ``seeder`` 50 % / ``drive`` 30 % / ``idle`` 20 % (:data:`PROFILES`), with slopes 40 %;
* 1, 2, 5, 10, 20 or 50 Hz; work plus rests 1-3 h, at most :data:`MAX_SAMPLES` samples;
* start full 40 % or part-charged (limit + 20 % to 95 %), rested or not 50/50 (unrested: right
  after an unrecorded dock charge or drive-down);
* 0-2 rests of 0-2 h; 0-2 opportunity charges of 5-20 min at constant current; a dock CC-CV
  charge to full in half of the missions at <= 10 Hz (:func:`charge`: a charger's control loop,
  one solver step per 2-s step; LFP 14.4 V, SLA 13.0 V, as Sulzer2019 has no end-of-charge
  rise), the charge current SLA 0.15-0.3 C, LFP 0.2-1 C;
* ambient -10 to 40 degC; LFP with the lumped thermal model (the recorded temperature is the
  cell's), SLA isothermal at the ambient (its lumped model was 7x slower a step);
* sensors within :data:`CORPUS_SENSORS`; pack capacity x0.95-1.05 (electrode width) and
  resistance x0.85-1.15 (a series resistance, ``(x - 1) * Pack.resistance_ohm``); the
  reference SoC is over that pack's own measured reference capacity.

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
* a solution is sampled by time (``t_eval`` at the sample stamps), never by solver step;
* every mission passes :func:`check_recording` before it is written (finite, SoC within [0, 1],
  the voltage answering every current step in the same sample, rest voltages in SoC order);
  a corpus mission that fails is reported with its seed and skipped.
"""

from __future__ import annotations

import argparse
import itertools
import math
import shutil
import textwrap
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]

from soc_estimator_ros.messages import (  # noqa: E402
    BATTERY_STATE,
    FLOAT64_ARRAY,
    bridge_state,  # noqa: E402
)
from soc_estimator_ros.messages import TECHNOLOGY_BY_CHEMISTRY as TECH  # noqa: E402
from soc_estimator_ros.recordings import (  # noqa: E402
    CELL_REFERENCE_TOPIC,
    REFERENCE_TOPIC,
    STATE_TOPIC,
    battery_state_message,
    float64_array_message,
    write_battery_bag,
)
from soc_estimator_ros.recordings import (
    write_bag as write_rosbag,
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
    #: Corpus pack spread (``--corpus``): the cell's electrode width (so its area, capacity and
    #: heat capacity) times this; the bundled packs have 1.
    capacity_x: float = 1.0
    #: Corpus pack spread: a series (contact) resistance added at the pack terminals, negative
    #: for a pack below the bundled one's resistance; the bundled packs have 0.
    series_resistance_ohm: float = 0.0
    #: PyBaMM's lumped thermal model (LFP corpus missions): the cell warms under load.
    thermal: bool = False
    #: The dock's CC-CV charger: its constant voltage (pack; LFP 3.60 V per cell, as
    #: runtime/charging.py expects; SLA below, Sulzer2019 has no end-of-charge rise) and the
    #: resistance its loop assumes (above the pack's over one control step: no overshoot).
    charge_voltage_v: float = 14.4
    charge_loop_ohm: float = 0.3
    #: The pack's resistance the corpus spread is a fraction of: the voltage drop 5 s into a
    #: 1 C discharge step from rest at 50 % SoC and 25 degC, per ampere (measured on this
    #: simulator, ``pack_resistance_ohm``).
    resistance_ohm: float = 0.0
    #: Ageing (``--aged``), LFP only: the cell's cyclable lithium (loss of lithium inventory:
    #: the graphite's lithium before the full state is set) and both electrodes' active
    #: material volume fractions (loss of active material) times these; the SLA pack ages by
    #: ``capacity_x`` (active plate area) instead. 1 for a fresh pack.
    lithium_x: float = 1.0
    active_material_x: float = 1.0
    #: The Li-ion packs' PyBaMM parameter set (SPMe): Prada2013 (A123 26650 LFP/graphite) for
    #: the LFP pack, Chen2020 (LG M50 21700 NMC811/graphite-SiOx) for the Li-ion pack.
    parameter_set: str = "Prada2013"
    #: The cell's voltage window for its initial (full) state: Prada2013 2.0-3.6 V, Chen2020's
    #: own 2.5-4.2 V.
    cell_window_v: tuple[float, float] = (2.0, 3.6)
    #: OCV hysteresis (``--hysteresis``), LFP only: the gap (V, per cell) between the LFP
    #: electrode's delithiation (charge) and lithiation (discharge) OCPs, PyBaMM's one-state
    #: hysteresis on the positive electrode (:func:`hysteresis_parameters`). 0: no hysteresis,
    #: the model and parameters of every other bag, untouched.
    ocp_hysteresis_v: float = 0.0
    #: The charge over which the hysteresis state moves 1 - 1/e of the way from one branch to
    #: the other, a fraction of ``cell_capacity_ah`` (used only with ``ocp_hysteresis_v``).
    hysteresis_decay_soc: float = 0.02

    @property
    def current_scale(self) -> float:
        """Cell current per pack ampere."""
        return self.cell_capacity_ah / self.pack_capacity_ah


#: The simulated SLA pack's charge voltage: Sulzer2019's full model has no end-of-charge
#: voltage rise (no gassing, no sulphate running out), so at the real pack's 14.4 V it would
#: charge on to twice its capacity; under the C/20 cut-off it reads 13.00 V at 98 % and
#: 13.02 V at 100 %, so the CC-CV charge holds 13.0 V and ends near full.
SLA_CHARGE_VOLTAGE_V = 13.0

PACKS = {
    # Sulzer2019's "17 Ah" cell delivers 21.75 Ah at C/20 to 1.75 V; SLA packs are rated at
    # C/20, so the current is scaled by 21.75/5 to make the pack a 5 Ah (C/20) pack.
    # resistance_ohm: measured here (1 C, 5 s, 50 %, 25 degC): 0.139 and 0.0465 ohm.
    "sla": Pack(
        "sla",
        6,
        21.75,
        5.0,
        10.5,
        0.40,
        TECH["sla"],
        "AJC-12V5AH-SIM",
        charge_loop_ohm=0.4,
        resistance_ohm=0.139,
        charge_voltage_v=SLA_CHARGE_VOLTAGE_V,
    ),
    "lfp": Pack(
        "lfp",
        4,
        2.3,
        6.0,
        10.0,
        0.20,
        TECH["lfp"],
        "ROYPOW-12V6AH-SIM",
        charge_loop_ohm=0.15,
        resistance_ohm=0.0465,
    ),
    # Seed 001's 4-cell series Li-ion pack: Chen2020's LG M50 (5 Ah nominal, 2.5-4.2 V) as
    # it is, 4S: 14.4 V nominal, 10.0 V cut-off, charged at 16.8 V. Its pulse test and
    # identification (config/li_ion_4s_chen2020.yaml) and cell-by-cell missions (--cells
    # --chemistry li_ion); no scenario corpus. resistance_ohm measured here as the others'.
    "li_ion": Pack(
        "li_ion",
        4,
        5.0,
        5.0,
        10.0,
        0.20,
        TECH["li_ion"],
        "LGM50-4S-SIM",
        charge_voltage_v=16.8,
        resistance_ohm=0.107,
        parameter_set="Chen2020",
        cell_window_v=(2.5, 4.2),
    ),
}


class PackSim:
    """One pack in PyBaMM, stepped segment by segment at constant current."""

    def __init__(self, pack: Pack, temp_c: float) -> None:
        import pybamm

        pybamm.set_logging_level("ERROR")
        self.pack = pack
        if pack.thermal and pack.chemistry != "lfp":
            raise ValueError("the lumped thermal model is used for the LFP pack only")
        if pack.chemistry != "lfp" and (pack.lithium_x, pack.active_material_x) != (1.0, 1.0):
            raise ValueError("lithium and active material ageing is the LFP pack's")
        if pack.chemistry == "sla":
            model = pybamm.lead_acid.Full()
            pv = pybamm.ParameterValues("Sulzer2019")
            pv["Initial State of Charge"] = 1.0
            # Events on the cell voltage; the pack's own cut-off is applied by this tool.
            pv["Upper voltage cut-off [V]"] = 2.7
            pv["Lower voltage cut-off [V]"] = 1.5
        else:
            options = {"thermal": "lumped"} if pack.thermal else {}
            if pack.ocp_hysteresis_v:
                if pack.chemistry != "lfp":
                    raise ValueError("the OCV hysteresis is the LFP pack's")
                options = {**options, "open-circuit potential": HYSTERESIS_OCP_OPTION}
            model = pybamm.lithium_ion.SPMe(options=options)
            pv = pybamm.ParameterValues(pack.parameter_set)
            if pack.thermal:
                pv.update(lumped_thermal_parameters(pybamm), check_already_exists=False)
            if pack.graphite_diffusivity_x != 1.0:
                key = "Negative particle diffusivity [m2.s-1]"
                pv[key] = pv[key] * pack.graphite_diffusivity_x
            for key in (
                "Negative electrode active material volume fraction",
                "Positive electrode active material volume fraction",
            ):
                pv[key] = pv[key] * pack.active_material_x
            # The cyclable lithium (set_initial_state counts it from the initial concentrations):
            # the graphite's concentration over the kept volume, times the lithium kept.
            key = "Initial concentration in negative electrode [mol.m-3]"
            pv[key] = pv[key] * pack.lithium_x / pack.active_material_x
            pv["Lower voltage cut-off [V]"], pv["Upper voltage cut-off [V]"] = pack.cell_window_v
            if pack.ocp_hysteresis_v:
                pv.update(hysteresis_parameters(pv, pack), check_already_exists=False)
                # 100 %: the upper limit on the charge branch, the hysteresis state there (+1),
                # as a charge to full leaves it (PyBaMM's initial state "charge" direction).
                pv = pv.set_initial_state(1.0, direction="charge", options=options, inplace=False)
            else:
                pv = pv.set_initial_state(1.0, inplace=False)  # 100 %: OCV at the upper limit
            # Solver events only (set after the initial state, which uses the window): a cold
            # pack sags below 2.0 V/cell on a 38 A peak; the pack cut-off is this tool's job.
            pv["Upper voltage cut-off [V]"] = pack.cell_window_v[1] + 0.2
            pv["Lower voltage cut-off [V]"] = 1.5
        if pack.capacity_x != 1.0:  # area: capacity and every per-area quantity
            for key in (
                "Electrode width [m]",
                "Cell volume [m3]",
                "Cell cooling surface area [m2]",
            ):
                if key in pv.keys():
                    pv[key] = pv[key] * pack.capacity_x
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
        self.last_current_a = 0.0
        #: The hysteresis state (PyBaMM's, -1 discharge branch .. +1 charge branch) at the end
        #: of the last segment and at the samples so far; only with ``ocp_hysteresis_v``.
        self.last_h = 1.0
        self.h_samples: list[np.ndarray] = []

    def segment(
        self, duration_s: float, current_a: float, sample_times: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Hold ``current_a`` (pack, discharge +) for ``duration_s``; sample the terminal
        voltage, the discharged charge and the cell temperature (degC; the ambient when
        isothermal) at ``sample_times`` (absolute, within [t, t + duration))."""
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
        if self.pack.series_resistance_ohm != 0.0:
            v = v - current_a * self.pack.series_resistance_ohm
        q = last["Discharge capacity [A.h]"].entries / self.pack.current_scale
        v_s = np.interp(rel, t_rel, v)
        q_s = np.interp(rel, t_rel, q)
        if self.pack.thermal:
            temp = last["X-averaged cell temperature [K]"].entries - 273.15
            temp_s = np.interp(rel, t_rel, temp)
        else:
            temp_s = np.full(rel.size, self.temp_c)
        if self.pack.ocp_hysteresis_v:
            h = last[HYSTERESIS_STATE].entries
            self.h_samples.append(np.interp(rel, t_rel, h))
            self.last_h = float(h[-1])
        self.t_s += duration_s
        self.discharged_ah = float(q[-1])
        self.last_v = float(v[-1])
        self.last_current_a = float(current_a)
        return v_s, q_s, temp_s


def lumped_thermal_parameters(pybamm) -> dict[str, float]:
    """What Prada2013 lacks for PyBaMM's lumped thermal model: layer densities, heat capacities
    and current collectors from Marquis2019 (a generic Li-ion cell), the geometry of the A123
    26650 (65 mm x 26 mm: 34.5 cm3, 63.7 cm2 of surface) and 10 W/m2/K to the air inside the
    pack's enclosure (natural convection)."""
    donor = pybamm.ParameterValues("Marquis2019")
    keys = [k for k in donor.keys() if "current collector" in k or k.endswith("[J.kg-1.K-1]")]
    keys += [k for k in donor.keys() if k.endswith("density [kg.m-3]")]
    values = {k: donor[k] for k in keys}
    values["Cell volume [m3]"] = math.pi * 0.013**2 * 0.065
    values["Cell cooling surface area [m2]"] = 2 * math.pi * 0.013 * 0.065 + 2 * math.pi * 0.013**2
    values["Total heat transfer coefficient [W.m-2.K-1]"] = 10.0
    return values


#: OCV hysteresis (``Pack.ocp_hysteresis_v``, ``--hysteresis``): PyBaMM's "one-state hysteresis"
#: (Axen et al. 2022, J. Energy Storage, doi:10.1016/j.est.2022.103985; the option PyBaMM also calls
#: "Axen") on the positive (LFP) electrode, the graphite keeping its single OCP. One state h per
#: electrode, dh/dt = gamma * i_vol / (F c_max eps) * (1 - sign(i_vol) h) / 2: driven by the
#: reaction current and frozen at zero current, so a rest keeps the branch of the charge or
#: discharge before it; the OCP is (1 + h)/2 U_delith + (1 - h)/2 U_lith. PyBaMM's "current sigmoid"
#: option is no use here: its h is 1 - 2 sigmoid(I), 0 at rest (the mid curve, no memory);
#: "one-state differential capacity hysteresis" (Wycisk) scales gamma by the differential capacity
#: to a power (its switching factor), near infinite on LFP's plateau: a branch change that crawls
#: there (with the power 0 it is this model).
HYSTERESIS_OCP_OPTION = ("single", "one-state hysteresis")
HYSTERESIS_STATE = "X-averaged positive electrode hysteresis state"
#: The LFP cell's charge/discharge OCV gap at rest, 16 mV per cell (64 mV for the 4S pack).
#: LFP's charge and discharge OCVs stay apart however slow the current and however long the
#: rest (Dreyer et al. 2010, Nature Materials 9, 448: the gap is thermodynamic, from the
#: many-particle electrode); roughly 10-20 mV per cell is reported for LFP cells, and Plett's
#: ESC model (Battery Management Systems vol. I, ch. 2) carries it as one state driven by the
#: current. Prada2013's single OCP (Afshar2017's LFP curve) is taken as the middle: the
#: lithiation (discharge) branch 8 mV below it, the delithiation (charge) branch 8 mV above.
LFP_HYSTERESIS_GAP_V = 0.016
#: The branch change's e-folding charge, 2 % of the cell's nominal capacity (2.06 % of the
#: reference capacity): 63 % of the way after 2 %, 95 % after 6 % (Plett's ESC model: the
#: hysteresis decays exponentially with the charge passed, over a few % of SoC).
LFP_HYSTERESIS_DECAY_SOC = 0.02


def positive_electrode_capacity_ah(pv) -> float:
    """The positive electrode's full lithiation capacity (Ah, one cell): room for 3.29 Ah in
    Prada2013's LFP."""
    f = 96485.33212  # C/mol
    return (
        pv["Positive electrode active material volume fraction"]
        * pv["Positive electrode thickness [m]"]
        * pv["Maximum concentration in positive electrode [mol.m-3]"]
        * pv["Electrode width [m]"]
        * pv["Electrode height [m]"]
        * f
        / 3600.0
    )


def hysteresis_decay_rate(pv, pack: Pack) -> float:
    """PyBaMM's hysteresis decay rate gamma (per unit of the electrode's stoichiometry, both
    directions) for ``pack.hysteresis_decay_soc``: h moves towards the branch of the current
    as dh/dsto = gamma (1 -/+ h)/2, so its e-folding stoichiometry is 2/gamma, the charge
    decay_soc x the cell's nominal capacity over the electrode's capacity."""
    q_p_ah = positive_electrode_capacity_ah(pv)
    return 2.0 * q_p_ah / (pack.hysteresis_decay_soc * pack.cell_capacity_ah)


def hysteresis_parameters(pv, pack: Pack) -> dict:
    """The parameters of :data:`HYSTERESIS_OCP_OPTION` on the positive electrode: its
    lithiation and delithiation OCPs (the parameter set's OCP -/+ half the gap) and decay rates;
    the initial state is set by ``set_initial_state`` (the charge branch at 100 %)."""
    ocp = pv["Positive electrode OCP [V]"]
    half = 0.5 * pack.ocp_hysteresis_v

    def lithiation(sto):
        return ocp(sto) - half

    def delithiation(sto):
        return ocp(sto) + half

    gamma = hysteresis_decay_rate(pv, pack)
    return {
        "Positive electrode lithiation OCP [V]": lithiation,
        "Positive electrode delithiation OCP [V]": delithiation,
        "Positive particle lithiation hysteresis decay rate": gamma,
        "Positive particle delithiation hysteresis decay rate": gamma,
    }


@dataclass
class Recording:
    """True signals at the sample stamps (pack level, discharge +)."""

    t_s: list[np.ndarray] = field(default_factory=list)
    current_a: list[np.ndarray] = field(default_factory=list)
    voltage_v: list[np.ndarray] = field(default_factory=list)
    discharged_ah: list[np.ndarray] = field(default_factory=list)
    temperature_c: list[np.ndarray] = field(default_factory=list)

    def add(self, t, i, v, q, temp=None) -> None:
        self.t_s.append(t)
        self.current_a.append(np.full(t.size, float(i)))
        self.voltage_v.append(v)
        self.discharged_ah.append(q)
        if temp is not None:
            self.temperature_c.append(temp)

    def arrays(self):
        return tuple(
            np.concatenate(x)
            for x in (self.t_s, self.current_a, self.voltage_v, self.discharged_ah)
        )

    def temperatures(self) -> np.ndarray:
        return np.concatenate(self.temperature_c)


def decimated(rec: Recording, every: int, rest_tail_s: float = 300.0) -> Recording:
    """``rec`` (1 Hz) with every ``every``-th sample kept, and the first sample of each
    current (its step answered in that sample), the last ``rest_tail_s`` of a rest whole (the
    current sensor's offset is read there: five 2-minute samples of a 40-mA quantizer read a
    -16 mA offset as +40 mA, and the C/20 capacity 22 % low), and the last sample above the
    cut-off (the 1-Hz recording's last, past the crossing, is a fraction of a second beyond
    the reference capacity: its SoC below 0)."""
    counts = np.cumsum([0] + [x.size for x in rec.t_s])
    t = np.concatenate(rec.t_s)
    current = np.concatenate(rec.current_a)
    n = int(counts[-1])
    steps = np.flatnonzero(np.diff(current) != 0.0) + 1
    rest_tail = [
        np.flatnonzero((current[k0:k1] == 0.0) & (t[k0:k1] > t[k1 - 1] - rest_tail_s)) + k0
        for k0, k1 in zip(np.r_[0, steps], np.r_[steps, n], strict=True)
    ]
    keep = np.unique(np.concatenate([np.arange(0, n - 1, every), steps, [n - 2], *rest_tail]))
    out = Recording()
    for j in range(len(rec.t_s)):
        k = keep[(keep >= counts[j]) & (keep < counts[j + 1])] - counts[j]
        if k.size:
            temp = rec.temperature_c[j][k] if rec.temperature_c else None
            out.add(
                rec.t_s[j][k],
                rec.current_a[j][0],
                rec.voltage_v[j][k],
                rec.discharged_ah[j][k],
                temp,
            )
    return out


def run_segments(
    sim: PackSim, segments, rec: Recording | None, rate_hz=10.0, tail_rate_hz=None, head_s=300.0
):
    """Simulate ``(duration_s, current_a)`` segments; record samples when ``rec`` is given.

    With ``tail_rate_hz``, a segment's samples after its first ``head_s`` are logged at that
    slower rate (long rests of lab tests).
    """
    for duration, current in segments:
        t0 = sim.t_s
        if rec is None:
            sim.segment(duration, current, np.array([], dtype=float))
            continue
        n = int(round(duration * rate_hz))
        times = t0 + np.arange(n) / rate_hz
        if tail_rate_hz is not None and duration > head_s:
            keep = (times - t0 < head_s) | (
                np.isclose(((times - t0) * tail_rate_hz) % 1.0, 0.0, atol=1e-6)
            )
            times = times[keep]
        times = np.round(times, 6)
        v, q, temp = sim.segment(duration, current, times)
        rec.add(times, current, v, q, temp)


# -- profiles -------------------------------------------------------------------------------
@dataclass(frozen=True)
class ChargePlan:
    """A charge at the dock: constant current ``current_a`` (magnitude) until the pack reaches
    ``voltage_v``, then that voltage held (the current tapering) until ``cutoff_a``; or, for an
    opportunity charge, whatever of that fits in ``max_s``."""

    current_a: float
    voltage_v: float
    cutoff_a: float = 0.0
    max_s: float = math.inf


#: The charger's control loop: a new current every CHARGE_STEP_S; CHARGE_COARSE_S steps while
#: the voltage, rising as fast as over the last step, stays below the charge voltage by more
#: than CHARGE_NEAR_V for three coarse steps (the CC phase far from the CV switch).
CHARGE_STEP_S = 2.0
CHARGE_COARSE_S = 30.0
CHARGE_NEAR_V = 0.05


def charge(sim: PackSim, plan: ChargePlan, rec: Recording | None, rate_hz: float) -> float:
    """Charge per ``plan`` in constant-current steps of a charger's control loop (each a
    separate solver step, as :func:`run_segments`): the current follows
    ``I += (V_cv - V) / charge_loop_ohm``, capped at the CC current, so the voltage holds at
    ``V_cv`` and the current tapers. Returns the time charged (s)."""
    magnitude = plan.current_a
    elapsed = 0.0
    reached_cv = False
    rise_v_per_s = math.inf  # unknown before the first charge step
    while elapsed < plan.max_s - 1e-9:
        error_v = plan.voltage_v - sim.last_v
        far = error_v > max(CHARGE_NEAR_V, 3.0 * CHARGE_COARSE_S * rise_v_per_s)
        step = min(CHARGE_COARSE_S if far else CHARGE_STEP_S, plan.max_s - elapsed)
        v_before = sim.last_v
        run_segments(sim, [(step, -magnitude)], rec, rate_hz)
        elapsed += step
        rise_v_per_s = max(0.0, sim.last_v - v_before) / step if elapsed > step else math.inf
        error_v = plan.voltage_v - sim.last_v
        reached_cv = reached_cv or error_v <= 0.0
        magnitude = float(
            np.clip(magnitude + error_v / sim.pack.charge_loop_ohm, 0.0, plan.current_a)
        )
        if reached_cv and magnitude <= plan.cutoff_a:
            break
    return elapsed


def step_segments(current_a: float, step_s: float, n_steps: int) -> list[tuple[float, float]]:
    """A 10-min rest, then ``n_steps`` steps of ``current_a`` for ``step_s`` with 1-h rests."""
    segs = [(600.0, 0.0)]
    for _ in range(n_steps):
        segs += [(step_s, current_a), (3600.0, 0.0)]
    return segs


def pulse_test_segments(pack: Pack) -> list[tuple[float, float]]:
    """Seed 000 §2.1: rest, then 30-min pulses of ~10 % SoC each with 1-h rests."""
    current = 0.2 * pack.pack_capacity_ah  # 10 % in 30 min (the paper's 13.5 / 12 ohm loads)
    n_pulses = 6 if pack.chemistry == "sla" else 8  # to 40 % (SLA) and 20 % (LFP, Li-ion)
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


#: What the robot does, one activity at a time (:func:`mission`).
ACTIVITIES = ("forward", "backward", "uphill", "downhill", "turn", "idle")
#: Electronics always on while the robot works (A); a parked robot's bridge alone draws REST_A.
ELECTRONICS_A = 0.35
REST_A = 0.05


@dataclass(frozen=True)
class Profile:
    """A mission profile: how often each of :data:`ACTIVITIES` is drawn (probabilities in that
    order) and whether the seeder's actuators pulse while driving forward."""

    name: str
    p: tuple[float, ...]
    actuators: bool

    def with_slopes(self) -> Profile:
        """Half of the flat forward and backward driving moved to slopes (uphill ~18 A, the
        heavy segments; downhill with regenerative braking), half each."""
        fwd, bwd, up, down, turn, idle = self.p
        flat = 0.5 * (fwd + bwd)
        return Profile(
            f"{self.name}+slopes",
            (0.5 * fwd, 0.5 * bwd, up + 0.5 * flat, down + 0.5 * flat, turn, idle),
            self.actuators,
        )


PROFILES = {
    # The bundled field runs' mission (the seeder sowing a field).
    "seeder": Profile("seeder", (0.30, 0.12, 0.10, 0.10, 0.08, 0.30), True),
    # Transport between fields: mostly forward, few stops, no seeding.
    "drive": Profile("drive", (0.55, 0.05, 0.05, 0.05, 0.15, 0.15), False),
    # Waiting at the field's edge: electronics on, a few short moves.
    "idle": Profile("idle", (0.08, 0.02, 0.02, 0.02, 0.03, 0.83), False),
}


def mission(rng: np.random.Generator, pack: Pack, profile: Profile = PROFILES["seeder"]):
    """Endless seeded robot mission: yields (duration_s, pack current A) segments.

    Two drive motors (seed 000 Table 2: Ampflow E30-150, 514 W peak), electronics always on,
    seeder linear actuators, flat and sloped ground forward and backward, idle stops; how often
    each is drawn is the ``profile``'s (the bundled field runs: ``seeder``).
    """
    electronics = ELECTRONICS_A
    while True:
        activity = rng.choice(list(ACTIVITIES), p=list(profile.p))
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
            if activity == "forward" and profile.actuators and rng.random() < 0.15:
                yield seg, electronics + level + 3.0  # seeder actuators extend
                continue
            yield seg, electronics + level


def quantize(x: np.ndarray, step: float) -> np.ndarray:
    return np.round(x / step) * step


@dataclass(frozen=True)
class SensorRanges:
    """Where :meth:`SensorModel.draw` draws a bag's sensor errors: uniform within the
    ``(low, high)`` pairs, one of the choices for the steps; without noise ranges the noise
    and steps are the defaults of :class:`SensorModel`."""

    current_gain: tuple[float, float]
    current_offset_a: tuple[float, float]
    voltage_gain: tuple[float, float]
    current_noise_a: tuple[float, float] | None = None
    current_step_a: tuple[float, ...] = ()
    voltage_noise_v: tuple[float, float] | None = None
    voltage_adc_bits: tuple[int, ...] = ()  # over 16 V


#: The bundled bags' sensors (bags/README.md, "Sensors as on the robot").
BUNDLED_SENSORS = SensorRanges((-0.008, 0.008), (-0.03, 0.03), (-5e-4, 5e-4))
#: The corpus missions' (bags/README.md, "Scenario corpus"): Hall sensors from a calibrated
#: LEM to an uncalibrated ACS712, 10- to 16-bit voltage ADCs.
CORPUS_SENSORS = SensorRanges(
    current_gain=(-0.015, 0.015),
    current_offset_a=(-0.06, 0.06),
    voltage_gain=(-1e-3, 1e-3),
    current_noise_a=(0.01, 0.08),
    current_step_a=(0.01, 0.02, 0.04, 0.08),
    voltage_noise_v=(0.001, 0.005),
    voltage_adc_bits=(10, 12, 16),
)


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
    def draw(cls, rng: np.random.Generator, ranges: SensorRanges | None = None) -> SensorModel:
        """Errors drawn within ``ranges`` (the bundled bags': :data:`BUNDLED_SENSORS`)."""
        r = BUNDLED_SENSORS if ranges is None else ranges
        drawn = cls(
            current_gain=float(rng.uniform(*r.current_gain)),
            current_offset_a=float(rng.uniform(*r.current_offset_a)),
            voltage_gain=float(rng.uniform(*r.voltage_gain)),
        )
        if r.current_noise_a is None or r.voltage_noise_v is None:  # the bundled bags' noise
            return drawn
        return replace(
            drawn,
            current_noise_a=float(rng.uniform(*r.current_noise_a)),
            current_step_a=float(rng.choice(r.current_step_a)),
            voltage_noise_v=float(rng.uniform(*r.voltage_noise_v)),
            voltage_step_v=16.0 / 2.0 ** int(rng.choice(r.voltage_adc_bits)),
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
#: A current step the voltage must answer in the same sample (the smallest designed step is
#: C/20, 0.25 A).
STEP_MIN_A = 0.2
#: A rest: the true current within this (the bridge alone, 50 mA) for at least REST_PROBE_S.
REST_MAX_A = 0.1
#: Rests are compared like with like: the voltage this long into each rest.
REST_PROBE_S = 300.0
#: Rest voltages are ordered only between rests this far apart in SoC (the LFP plateau falls
#: by a few mV over 5 %, less than what an unfinished relaxation leaves).
REST_MIN_DSOC = 0.1


def voltage_step_failures(i: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Indices ``k`` of the current steps ``i[k] -> i[k + 1]`` (|dI| > STEP_MIN_A) that do not
    move the voltage in the same sample, the opposite way (a frozen solver).

    The move is taken beyond the voltage's drift over the sample before, at the same current:
    at 1-2 Hz under a heavy load the voltage falls by ~10 mV a sample, more than a 0.3 A step
    moves it, and a frozen solver would show just that drift. A step right after another
    (a one-sample segment, at 1-2 Hz) has no such sample and is left out: a cold pack's
    voltage moves by as much over the second of a 27 A start-up as a 7 A step moves it."""
    di = np.diff(i)
    dv = np.diff(v)
    steps = np.flatnonzero(np.abs(di) > STEP_MIN_A)
    steps = steps[(steps > 0) & (di[np.maximum(steps - 1, 0)] == 0.0)]
    answer = dv[steps] - dv[steps - 1]
    ok = (answer * di[steps] < 0) & (np.abs(answer) > 0.002 * np.abs(di[steps]))
    return steps[~ok]


def rest_probes(t: np.ndarray, i: np.ndarray, v: np.ndarray, soc: np.ndarray) -> list[int]:
    """The sample REST_PROBE_S into each rest that follows a discharge (the mean current over
    the minute before it positive): rests after a charge relax from above and are left out."""
    resting = np.abs(i) <= REST_MAX_A
    edges = np.flatnonzero(np.diff(np.concatenate([[0], resting.astype(np.int8), [0]])))
    probes = []
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        k = int(np.searchsorted(t, t[start] + REST_PROBE_S))
        if k >= stop:  # shorter than REST_PROBE_S
            continue
        before = (t >= t[start] - 60.0) & (t < t[start])
        if start == 0 or not before.any() or np.mean(i[before]) <= 0.0:
            continue
        probes.append(k)
    return probes


def rest_order_failures(
    t: np.ndarray, i: np.ndarray, v: np.ndarray, soc: np.ndarray
) -> list[tuple[float, float]]:
    """Pairs of rests (their SoCs) at least REST_MIN_DSOC apart whose probed voltages
    (:func:`rest_probes`) are not in the order of their SoCs."""
    probes = rest_probes(t, i, v, soc)
    bad = []
    for a in probes:
        for b in probes:
            if soc[a] - soc[b] >= REST_MIN_DSOC and not v[a] > v[b]:
                bad.append((round(float(soc[a]), 3), round(float(soc[b]), 3)))
    return bad


def check_recording(
    name: str,
    t,
    i,
    v,
    soc,
    capacity_ah,
    rest_ends: list[int] | list[list[int]] | None,
    sample_period_s: float | None = None,
    temp=None,
) -> None:
    """Refuse to write a bag whose simulated signals are not physical (module docstring)."""
    signals = [t, i, v, soc] + ([] if temp is None else [temp])
    if not all(np.all(np.isfinite(x)) for x in signals):
        raise RuntimeError(f"{name}: non-finite values")
    if not np.all(np.diff(t) > 0):
        raise RuntimeError(f"{name}: stamps not strictly increasing")
    if sample_period_s is not None and not np.allclose(np.diff(t), sample_period_s, atol=1e-6):
        raise RuntimeError(f"{name}: samples off the {sample_period_s} s grid")
    if np.min(soc) < 0.0 or np.max(soc) > 1.0:
        raise RuntimeError(f"{name}: reference SoC {np.min(soc):.4f} .. {np.max(soc):.4f}")
    bad = voltage_step_failures(i, v)
    if bad.size:
        k = int(bad[0])
        raise RuntimeError(
            f"{name}: {bad.size} current steps do not move the voltage in the same sample "
            f"(first at t={t[k + 1]:.1f} s: dI={i[k + 1] - i[k]:+.2f} A, "
            f"dV={v[k + 1] - v[k]:+.4f} V)"
        )
    dv = np.diff(v)
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
    # Rest ends in the order of falling SoC; a hysteretic pack's per branch (lists of lists).
    for ends in rest_ends if rest_ends and isinstance(rest_ends[0], list) else [rest_ends]:
        if not ends:
            continue
        rest_v = v[ends]
        if not np.all(np.diff(rest_v) < 0):
            raise RuntimeError(f"{name}: rest voltages do not fall with SoC: {rest_v}")
    disordered = rest_order_failures(t, i, v, soc)
    if disordered:
        raise RuntimeError(
            f"{name}: rest voltages out of SoC order (SoC pairs {disordered[:3]}, "
            f"{REST_PROBE_S:.0f} s into each rest)"
        )


# -- bags -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class BagSpec:
    name: str
    chemistry: str
    kind: str  # pulse_test | rate_test | load_test | slow_discharge | field_run | (corpus)
    # mission | (--aged, --sized) health_mission
    seed: int
    temp_c: float = 25.0
    start_soc: float = 1.0
    long_rest_s: float = 0.0
    storage: str = "mcap"
    description: str = ""
    #: Lab tests: the sample rate, and the rate past a segment's first 300 s.
    rate_hz: float = 10.0
    tail_rate_hz: float = 1.0


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
    BagSpec(
        "li_ion4s_pulse_test",
        "li_ion",
        "pulse_test",
        31,
        description="Seed 000 §2.1 pulse-discharge test on a 4S LG M50 pack (PyBaMM Chen2020): "
        "10 min rest, eight 30-min 1.0 A pulses (10 % SoC each) with 1-h rests, 100 % to 20 %; "
        "2 Hz, 0.5 Hz past each segment's first 5 minutes (bags/ stays under 80 MB).",
        rate_hz=2.0,
        tail_rate_hz=0.5,
    ),
    BagSpec(
        "li_ion4s_slow_discharge",
        "li_ion",
        "slow_discharge",
        32,
        description="C/20 (0.25 A) discharge from full to 10.0 V on the pack of "
        "li_ion4s_pulse_test, for the capacity and the OCV curve; logged every 2 minutes "
        "(bags/ stays under 80 MB).",
        rate_hz=1.0 / 120.0,
    ),
]

#: Not bundled (``--dev``, into a directory of your own): seeder missions from full to 20 %
#: with seeds apart from the field runs', on which ``benchmarks/studies/table_transfer.py`` fits the
#: 2RC's tables to see whether they carry over to the field runs (docs/identification.md); the
#: 4S Li-ion pack's pulse test at 5 degC, which config/li_ion_4s_chen2020.yaml is identified
#: from beside the bundled 25 degC one (``--dev --only li_ion4s_pulse_test_5c --out dev_bags``).
DEV_SPECS = [
    BagSpec(
        f"lfp_mission_{seed}",
        "lfp",
        "field_run",
        seed,
        description=f"Seeder mission from full to 20 % (seed {seed}; a dev bag, not bundled).",
    )
    for seed in (32, 34, 35, 36, 37, 38)
] + [
    BagSpec(
        "li_ion4s_pulse_test_5c",
        "li_ion",
        "pulse_test",
        33,
        temp_c=5.0,
        description="The pulse test of li_ion4s_pulse_test at 5 degC ambient (a dev bag: bags/ "
        "has no room for it; config/li_ion_4s_chen2020.yaml's 5 degC row).",
        rate_hz=2.0,
        tail_rate_hz=0.5,
    )
]


# -- the scenario corpus (--corpus) -----------------------------------------------------------
#: Corpus seeds start here; odd seeds are validation missions, even seeds tuning missions.
CORPUS_FIRST_SEED = 1000
#: The second word of every corpus random stream: one chemistry's seed 1001 is not another's.
CHEMISTRY_STREAM = {"sla": 1, "lfp": 2}
SAMPLE_RATES_HZ = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0)
#: A mission's work and rests stay within this many samples (50 Hz: one hour).
MAX_SAMPLES = 180_000
#: Dock charges (hours long) only in missions logged at this rate or slower.
DOCK_MAX_RATE_HZ = 10.0
#: The charger's taper cut-off (C of the nominal capacity; runtime/charging.py's FULL taper).
DOCK_CUTOFF_C = 0.05
#: Rested starts park this long after their unrecorded pre-phase.
PARK_S = 7200.0
#: Charge currents (C of the nominal capacity) a dock or an opportunity charger gives.
CHARGE_C = {"sla": (0.15, 0.3), "lfp": (0.2, 1.0)}


@dataclass(frozen=True)
class Scenario:
    """One corpus mission, every value drawn from its seed (:func:`draw_scenario`)."""

    chemistry: str
    seed: int
    profile: str
    slopes: bool
    sample_rate_hz: float
    ambient_c: float
    capacity_x: float
    resistance_x: float
    start_soc: float
    start_rested: bool
    work_s: float  # driving, working and idle stops (the profile), rests and charges apart
    rests: tuple[tuple[float, float], ...]  # (at this fraction of the work, duration s)
    opportunity_charges: tuple[tuple[float, float], ...]  # (fraction of the work, duration s)
    charge_c: float
    dock_soc: float | None  # the SoC the robot docks at (CC-CV to full); None: no dock charge
    sensors: SensorModel

    @property
    def split(self) -> str:
        return "validation" if self.seed % 2 else "tuning"

    @property
    def name(self) -> str:
        return f"{self.chemistry}_{self.split}_{self.seed}"

    def stream(self, word: int) -> np.random.Generator:
        """An independent random stream of this mission (1 work, 2 pre-phase, 3 sensors)."""
        return np.random.default_rng([self.seed, CHEMISTRY_STREAM[self.chemistry], word])

    def values(self) -> dict:
        """Every drawn value, for bag.yaml (the sensors have their own entry)."""
        out = {k: v for k, v in self.__dict__.items() if k != "sensors"}
        out["rests"] = [[round(a, 4), round(d, 1)] for a, d in self.rests]
        out["opportunity_charges"] = [
            [round(a, 4), round(d, 1)] for a, d in self.opportunity_charges
        ]
        return {k: round(v, 6) if isinstance(v, float) else v for k, v in out.items()}


def draw_scenario(chemistry: str, seed: int) -> Scenario:
    """Draw one mission from the corpus distribution (bags/README.md, "Scenario corpus").

    Every value is drawn whether it is used or not, so each keeps its meaning across seeds.
    """
    pack = PACKS[chemistry]
    rng = np.random.default_rng([seed, CHEMISTRY_STREAM[chemistry], 0])
    profile = str(rng.choice(list(PROFILES), p=[0.5, 0.3, 0.2]))
    slopes = bool(rng.random() < 0.4)
    rate_hz = float(rng.choice(SAMPLE_RATES_HZ))
    ambient_c = round(float(rng.uniform(-10.0, 40.0)), 1)
    capacity_x = round(float(rng.uniform(0.95, 1.05)), 4)
    resistance_x = round(float(rng.uniform(0.85, 1.15)), 4)
    full = bool(rng.random() < 0.4)
    part_soc = round(float(rng.uniform(pack.soc_limit + 0.2, 0.95)), 3)
    rested = bool(rng.random() < 0.5)
    recorded_s = min(float(rng.uniform(1.0, 3.0)) * 3600.0, MAX_SAMPLES / rate_hz)
    n_rests = int(rng.choice([0, 1, 2], p=[0.3, 0.4, 0.3]))
    rest_max_s = min(7200.0, recorded_s / 3.0)
    rests = tuple(
        sorted(
            (float(rng.uniform(0.1, 0.9)), float(rng.uniform(0.0, rest_max_s))) for _ in range(2)
        )
    )[:n_rests]
    n_opportunity = int(rng.choice([0, 1, 2], p=[0.5, 0.3, 0.2]))
    opportunity = tuple(
        sorted(
            (float(rng.uniform(0.2, 0.9)), 60.0 * float(rng.uniform(5.0, 20.0))) for _ in range(2)
        )
    )[:n_opportunity]
    charge_c = round(float(rng.uniform(*CHARGE_C[chemistry])), 3)
    docks = bool(rng.random() < 0.5) and rate_hz <= DOCK_MAX_RATE_HZ
    dock_soc = round(float(rng.uniform(pack.soc_limit + 0.02, pack.soc_limit + 0.2)), 3)
    sensors = SensorModel.draw(rng, CORPUS_SENSORS)
    return Scenario(
        chemistry=chemistry,
        seed=seed,
        profile=profile,
        slopes=slopes,
        sample_rate_hz=rate_hz,
        ambient_c=ambient_c,
        capacity_x=capacity_x,
        resistance_x=resistance_x,
        start_soc=1.0 if full else part_soc,
        start_rested=rested,
        work_s=round(recorded_s - sum(d for _, d in rests), 1),
        rests=rests,
        opportunity_charges=opportunity,
        charge_c=charge_c,
        dock_soc=dock_soc if docks else None,
        sensors=sensors,
    )


def scenario_pack(sc: Scenario, hysteresis: bool = False) -> Pack:
    """The bundled pack of ``sc.chemistry`` (with ``hysteresis``, LFP: the hysteretic one,
    :data:`HYSTERESIS_PACK`) with the mission's spread (and, LFP, warming)."""
    base = HYSTERESIS_PACK if hysteresis else PACKS[sc.chemistry]
    return replace(
        base,
        capacity_x=sc.capacity_x,
        series_resistance_ohm=(sc.resistance_x - 1.0) * base.resistance_ohm,
        thermal=sc.chemistry == "lfp",
    )


def on_grid(duration_s: float, rate_hz: float) -> float:
    """``duration_s`` as a whole number of sample periods (at least one)."""
    return max(1, round(duration_s * rate_hz)) / rate_hz


def discharge_to(sim: PackSim, soc, target: float, segments) -> None:
    """Unrecorded: run ``segments`` ((duration_s, current_a) pairs) until ``soc() <= target``."""
    while soc() > target:
        run_segments(sim, [next(segments)], None)


def dock_plan(sc: Scenario, pack: Pack) -> ChargePlan:
    """The dock's CC-CV charge to full."""
    c = pack.pack_capacity_ah
    return ChargePlan(sc.charge_c * c, pack.charge_voltage_v, DOCK_CUTOFF_C * c)


def start_phase(sim: PackSim, sc: Scenario, pack: Pack, soc) -> None:
    """Bring the pack to the mission's start, unrecorded: full and rested is the initial state;
    full and unrested just ended a dock charge (from 80 %, at C/5 down); part-charged starts
    were driven down from full (rested: at C/5, then parked PARK_S; unrested: by the mission's
    own profile, the recording starting at once)."""
    c5 = itertools.repeat((30.0, pack.pack_capacity_ah / 5.0))
    if sc.start_soc >= 1.0:
        if not sc.start_rested:
            discharge_to(sim, soc, 0.8, c5)
            charge(sim, dock_plan(sc, pack), None, 1.0)
        return
    if sc.start_rested:
        discharge_to(sim, soc, sc.start_soc, c5)
        run_segments(sim, [(PARK_S, 0.0)], None)
    else:
        discharge_to(sim, soc, sc.start_soc, mission(sc.stream(2), pack, mission_profile(sc)))


def mission_profile(sc: Scenario) -> Profile:
    profile = PROFILES[sc.profile]
    return profile.with_slopes() if sc.slopes else profile


def simulate_mission(sc: Scenario, pack: Pack, capacity_ah: float) -> dict:
    """The recorded mission: the profile's work, with the rests and opportunity charges at
    their fractions of the work, the dock charge when the SoC falls to ``dock_soc`` (or at
    the end, back at the dock); ends after ``work_s`` of work or at the pack's SoC limit."""
    sim = PackSim(pack, sc.ambient_c)
    soc = lambda: 1.0 - sim.discharged_ah / capacity_ah  # noqa: E731
    start_phase(sim, sc, pack, soc)
    rate = sc.sample_rate_hz
    events = sorted(
        [(a * sc.work_s, "rest", d) for a, d in sc.rests]
        + [(a * sc.work_s, "opportunity", d) for a, d in sc.opportunity_charges]
    )
    work = mission(sc.stream(1), pack, mission_profile(sc))
    rec = Recording()
    worked_s = 0.0
    docked = sc.dock_soc is None
    while worked_s < sc.work_s:
        if events and worked_s >= events[0][0]:
            _, kind, duration_s = events.pop(0)
            if kind == "rest":
                run_segments(sim, [(on_grid(duration_s, rate), REST_A)], rec, rate)
            else:
                limit_s = 10.0 * max(1, round(duration_s / 10.0))
                charge(sim, replace(dock_plan(sc, pack), cutoff_a=0.0, max_s=limit_s), rec, rate)
        elif sc.dock_soc is not None and not docked and soc() <= sc.dock_soc:
            charge(sim, dock_plan(sc, pack), rec, rate)
            docked = True
        elif soc() <= pack.soc_limit:
            break
        else:
            duration_s, current_a = next(work)
            duration_s = on_grid(duration_s, rate)
            run_segments(sim, [(duration_s, current_a)], rec, rate)
            worked_s += duration_s
    if not docked:  # back at the dock
        charge(sim, dock_plan(sc, pack), rec, rate)
    t, i, v, q = rec.arrays()
    temp = rec.temperatures()
    soc_ref = 1.0 - q / capacity_ah
    check_recording(sc.name, t, i, v, soc_ref, capacity_ah, None, 1.0 / rate, temp)
    out = {"t": t, "i": i, "v": v, "soc": soc_ref, "temp_c": sc.ambient_c, "temperature_c": temp}
    if pack.ocp_hysteresis_v:  # the true hysteresis state at the samples (--hysteresis)
        out["hysteresis_state"] = np.concatenate(sim.h_samples)
    return out


@cache
def base_capacity_ah(chemistry: str) -> float:
    """The bundled pack's reference capacity (isothermal, as :func:`scenario_capacity_ah`)."""
    return reference_capacity_ah(PACKS[chemistry])


def scenario_capacity_ah(pack: Pack) -> float:
    """The drawn pack's own reference capacity: C/20 at 25 degC to the cut-off, isothermal (at
    C/20 the lumped cell warms by hundredths of a kelvin)."""
    return reference_capacity_ah(replace(pack, thermal=False))


def check_capacity(sc: Scenario, capacity_ah: float) -> float:
    """The measured capacity over the bundled pack's; refuses a pack whose capacity did not move
    as drawn (within 1 % of ``capacity_x``)."""
    ratio = capacity_ah / base_capacity_ah(sc.chemistry)
    if abs(ratio / sc.capacity_x - 1.0) > 0.01:
        raise RuntimeError(f"{sc.name}: capacity x{ratio:.4f}, drawn x{sc.capacity_x:.4f}")
    return ratio


def describe(sc: Scenario) -> str:
    start = "full" if sc.start_soc >= 1.0 else f"part-charged ({sc.start_soc:.0%})"
    rested = "rested" if sc.start_rested else "unrested"
    dock = (
        "no dock charge"
        if sc.dock_soc is None
        else f"dock CC-CV to full when the SoC falls to {sc.dock_soc:.0%} (or at the end)"
    )
    return (
        f"Corpus mission ({sc.split}, seed {sc.seed}): {mission_profile(sc).name} profile, "
        f"starts {start} and {rested}, {len(sc.rests)} rest(s), "
        f"{len(sc.opportunity_charges)} opportunity charge(s), {dock}; ambient "
        f"{sc.ambient_c} degC, {sc.sample_rate_hz:g} Hz; pack capacity x{sc.capacity_x:.3f}, "
        f"resistance x{sc.resistance_x:.3f} of the bundled pack."
    )


def build_mission(sc: Scenario, out_dir: str, hysteresis: bool = False) -> dict:
    """Simulate, check and write one corpus mission (nothing is written if a check fails);
    ``hysteresis``: on the hysteretic LFP pack."""
    pack = scenario_pack(sc, hysteresis)
    capacity_ah = scenario_capacity_ah(pack)
    ratio = check_capacity(sc, capacity_ah)
    data = simulate_mission(sc, pack, capacity_ah)
    spec = BagSpec(sc.name, sc.chemistry, "mission", sc.seed, sc.ambient_c)
    spec = replace(spec, description=describe(sc))
    return write_mission(sc, spec, pack, data, capacity_ah, ratio, out_dir)


def write_mission(
    sc: Scenario, spec: BagSpec, pack: Pack, data: dict, capacity_ah: float, ratio: float, out_dir
) -> dict:
    """Write a simulated mission with its scenario, its pack's spread (``ratio``: the measured
    capacity over the bundled pack's) and, for the hysteretic pack, the hysteresis and its
    true state at the start and end in bag.yaml."""
    extra = {
        "split": sc.split,
        "scenario": sc.values(),
        "pack": {
            "capacity_x": sc.capacity_x,
            "capacity_x_measured": round(ratio, 4),
            "resistance_x": sc.resistance_x,
            "series_resistance_ohm": round(pack.series_resistance_ohm, 6),
            "thermal": "lumped" if pack.thermal else "isothermal",
        },
        "temperature_max_c": round(float(np.max(data["temperature_c"])), 2),
    }
    if pack.ocp_hysteresis_v:
        h = data["hysteresis_state"]
        extra["hysteresis"] = {
            **hysteresis_meta(pack),
            "state_start": round(float(h[0]), 4),
            "state_end": round(float(h[-1]), 4),
        }
    return write_bag(
        spec,
        data,
        capacity_ah,
        Path(out_dir),
        pack,
        sensors=sc.sensors,
        rng=sc.stream(3),
        start_ns=EPOCH_NS + sc.seed * 86_400 * 1_000_000_000,
        extra=extra,
    )


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
                        local.temperature_c[j][:cut],
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
        run_segments(sim, segs, rec, spec.rate_hz, spec.tail_rate_hz)
        counts = np.cumsum([x.size for x in rec.t_s])
        rest_ends = [int(counts[0]) - 1] + [int(counts[k]) - 1 for k in range(2, len(segs), 2)]
    elif spec.kind == "rate_test":
        segs = rate_test_segments(pack)
        run_segments(sim, segs, rec, spec.rate_hz, spec.tail_rate_hz)
        counts = np.cumsum([x.size for x in rec.t_s])
        rest_ends = [
            int(counts[k]) - 1 for k, (dur, cur) in enumerate(segs) if dur >= 600.0 and cur == 0.0
        ]
    elif spec.kind == "slow_discharge":
        slow_discharge(pack, rec)
        if spec.rate_hz < 1.0:
            rec = decimated(rec, round(1.0 / spec.rate_hz))
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


def write_bag(
    spec: BagSpec,
    data: dict,
    capacity_ah: float,
    out_dir: Path,
    pack: Pack,
    *,
    sensors: SensorModel | None = None,
    rng: np.random.Generator | None = None,
    start_ns: int | None = None,
    extra: dict | None = None,
) -> dict:
    """Write one bag and its bag.yaml and README. The bundled bags draw their sensors from
    ``spec.seed + 1000`` and start one day apart in :data:`SPECS` order; a corpus mission
    gives its own ``sensors``, noise ``rng``, ``start_ns`` and ``extra`` metadata."""
    if rng is None:
        rng = np.random.default_rng(spec.seed + 1000)
    if sensors is None:
        sensors = SensorModel.draw(rng)
    t, i, v, soc = data["t"], data["i"], data["v"], data["soc"]
    temp = data.get("temperature_c")
    if temp is None:
        temp = np.full(t.size, data["temp_c"])
    i_m, v_m, temp_m = sensors.measure(rng, i, v, temp)
    if start_ns is None:
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
    if extra:
        meta.update(extra)
    if pack.graphite_diffusivity_x != 1.0:
        meta["description"] += (
            f" Dev pack: the graphite's diffusivity x{pack.graphite_diffusivity_x:g}."
        )
    (bag / "bag.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    (bag / "README.md").write_text(bag_readme(meta))
    return meta


def bag_readme(meta: dict) -> str:
    s = meta["sensors"]
    adc_bits = round(math.log2(16.0 / s["voltage_step_v"]))
    return (
        f"""# {meta["name"]}

{meta["description"]}

- Chemistry: {meta["chemistry"]} (see ../README.md for the pack model and scaling);
  ambient {meta["ambient_temperature_c"]} degC.
- Duration {meta["duration_s"] / 3600.0:.2f} h, {meta["samples"]} samples at
  {meta["sample_rate_hz"]} Hz (median rate); SoC {meta["soc_start"]:.3f} -> {meta["soc_end"]:.3f}
  (reference capacity {meta["reference_capacity_ah"]} Ah); current
  {meta["current_min_a"]} .. {meta["current_max_a"]} A (discharge positive).
- Sensors: current gain error {s["current_gain"]:+.4f}, offset {s["current_offset_a"]:+.3f} A,
  noise {s["current_noise_a"]} A, quantized to {s["current_step_a"]} A; voltage gain error
  {s["voltage_gain"]:+.5f}, noise {s["voltage_noise_v"] * 1000:.1f} mV, {adc_bits}-bit ADC over 16 V
  ({s["voltage_step_v"] * 1000:.2f} mV steps); temperature noise {s["temperature_noise_c"]} degC.
- Storage: rosbag2 {meta["storage"]}, {COMPRESSION_TEXT[meta["storage"]]}. Seed {meta["seed"]}.
- `/battery/soc_reference` is the simulator's true SoC, not a measurement.
"""
        + (scenario_readme(meta) if "scenario" in meta else "")
        + (health_readme(meta) if "health" in meta else "")
        + (hysteresis_readme(meta) if "hysteresis" in meta else "")
    )


def hysteresis_readme(meta: dict) -> str:
    """A hysteretic pack's README lines (``--hysteresis``): its hysteresis, the test's pairs."""
    hy = meta["hysteresis"]
    items = [
        f'OCV hysteresis (bag.yaml `hysteresis`; ../README.md, "Hysteresis"): PyBaMM\'s '
        f"one-state hysteresis on the LFP electrode, gap {hy['gap_per_cell_v'] * 1000:g} mV per "
        f"cell ({hy['gap_pack_v'] * 1000:g} mV for the pack), the branch change's e-folding "
        f"charge {hy['decay_soc_of_nominal']:.0%} of the nominal capacity (PyBaMM decay rate "
        f"{hy['decay_rate']}); state +1 the charge branch, -1 the discharge branch."
    ]
    if "state_start" in hy:
        items.append(
            f"True hysteresis state {hy['state_start']:+.3f} at the start, "
            f"{hy['state_end']:+.3f} at the end."
        )
    for p in hy.get("pairs_1h", []):
        items.append(
            f"Rested 1 h at SoC {p['soc']:.3f}: {p['after_charge_v']:.4f} V after a charge, "
            f"{p['after_discharge_v']:.4f} V after a discharge ({p['gap_v'] * 1000:.1f} mV)."
        )
    return "".join(
        textwrap.fill(x, 95, initial_indent="- ", subsequent_indent="  ") + "\n" for x in items
    )


def scenario_readme(meta: dict) -> str:
    """A corpus mission's README lines: its split, pack spread and drawn scenario."""
    p, sc = meta["pack"], meta["scenario"]
    values = "\n".join(f"  - {k}: {v}" for k, v in sc.items())
    return f"""- Split: **{meta["split"]}** (corpus seed {meta["seed"]}; ../README.md, "Scenario
  corpus").
- Pack spread: capacity x{p["capacity_x"]} (measured x{p["capacity_x_measured"]}), resistance
  x{p["resistance_x"]} ({p["series_resistance_ohm"] * 1000:+.2f} mOhm in series); thermal model:
  {p["thermal"]} (highest cell temperature {meta["temperature_max_c"]} degC).
- Drawn scenario (bag.yaml `scenario`):
{values}
"""


def build(spec: BagSpec, capacity_ah: float, out_dir: str, pack: Pack) -> dict:
    data = simulate_bag(spec, capacity_ah, pack)
    return write_bag(spec, data, capacity_ah, Path(out_dir), pack)


def timed_mission(
    sc: Scenario, out_dir: str, hysteresis: bool = False
) -> tuple[Scenario, dict | str, float]:
    """:func:`build_mission`, its failure as a message (the mission is skipped), its wall time."""
    start = time.monotonic()
    try:
        result: dict | str = build_mission(sc, out_dir, hysteresis)
    except Exception as exc:  # any solver or check failure rejects this one mission
        result = f"{type(exc).__name__}: {exc}"
    return sc, result, time.monotonic() - start


def make_corpus(
    chemistries: list[str], seeds: list[int], out_dir: Path, jobs: int, hysteresis: bool = False
) -> int:
    """Every (seed, chemistry) mission not yet in ``out_dir``; rejected ones are reported with
    their seed and not written. Returns 0 (rejections are results, not errors).
    ``hysteresis``: LFP only, the same draws on the hysteretic pack."""
    if hysteresis and chemistries != ["lfp"]:
        raise SystemExit("--corpus --hysteresis: the hysteretic pack is LFP (--chemistry lfp)")
    out_dir.mkdir(parents=True, exist_ok=True)
    todo = [draw_scenario(c, seed) for seed in seeds for c in chemistries]
    todo = [sc for sc in todo if not (out_dir / sc.name / "bag.yaml").exists()]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(timed_mission, sc, str(out_dir), hysteresis) for sc in todo]
        for fut in futures:
            sc, result, wall_s = fut.result()
            if isinstance(result, str):
                print(f"REJECTED {sc.chemistry} seed {sc.seed} ({sc.name}): {result}", flush=True)
                continue
            print(
                f"{result['name']}: {result['duration_s'] / 3600:.2f} h at "
                f"{sc.sample_rate_hz:g} Hz, SoC {result['soc_start']:.3f} -> "
                f"{result['soc_end']:.3f}, {result['samples']} samples, {wall_s:.0f} s",
                flush=True,
            )
    return 0


# -- battery health: aged packs and packs of other sizes (--aged, --sized) -------------------
#: Health missions' seeds (validation, but for the ``*_tuning`` packs): 2000 + 10 x the pack's
#: index in :data:`HEALTH_PACKS` + the mission's number (1-3), with the chemistry as a second
#: word of every random stream, as in the corpus.
HEALTH_FIRST_SEED = 2000
#: The health missions' sample rate (small bags).
HEALTH_RATE_HZ = 2.0
#: A health mission: a rest at full, the seeder's work down to the pack's SoC limit plus up to
#: HEALTH_END_DSOC, a rest of HEALTH_REST_S (uniform) half-way down and another at the end.
HEALTH_START_REST_S = 300.0
HEALTH_REST_S = (1800.0, 3600.0)
HEALTH_END_DSOC = 0.05


@dataclass(frozen=True)
class HealthPack:
    """A pack of the battery-health data: a bundled pack aged (``aged*``; ``fresh`` is the
    control) or the bundled chemistry in another size (``sized``).

    ``capacity_x`` and ``resistance_x`` are what the ageing aims at (of the fresh pack's
    measured capacity and resistance); the pack is then measured (:func:`measure_health_pack`).
    LFP ages by loss of lithium inventory (``lithium_x``) and of active material in both
    electrodes (``active_material_x``); SLA by loss of active plate area (``capacity_x`` as the
    electrode width, the pores' acid with it). Both then get a series (film, contact)
    resistance that brings the measured 5-s drop to ``resistance_x`` of the fresh pack's.
    """

    name: str  # bag folders <name>_m<k>
    chemistry: str
    missions: int
    capacity_x: float = 1.0
    resistance_x: float = 1.0
    lithium_x: float = 1.0
    active_material_x: float = 1.0
    #: Another size (``--sized``): cells in series and the nominal capacity; the mission's
    #: currents times the nominal capacity over the bundled pack's (a robot sized to its pack).
    cells: int | None = None
    pack_capacity_ah: float | None = None
    serial: str = ""

    @property
    def sized(self) -> bool:
        return self.cells is not None

    @property
    def split(self) -> str:
        """``tuning`` for the packs the OCV's ageing law is chosen on, else ``validation``."""
        return "tuning" if self.name.endswith("_tuning") else "validation"

    def bag_name(self, k: int) -> str:
        return f"{self.name}_m{k}"

    def seed(self, k: int) -> int:
        return HEALTH_FIRST_SEED + 10 * HEALTH_PACKS.index(self) + k

    def electrochemistry(self) -> Pack:
        """The simulated pack before its series resistance (isothermal; the missions' LFP pack
        warms with the lumped model, as in the corpus)."""
        base = PACKS[self.chemistry]
        pack = replace(base, serial=self.serial or base.serial)
        if self.sized:
            scale = self.cells / base.cells
            pack = replace(
                pack,
                cells=self.cells,
                pack_capacity_ah=self.pack_capacity_ah,
                cutoff_v=base.cutoff_v * scale,
                charge_voltage_v=base.charge_voltage_v * scale,
                resistance_ohm=0.0,  # measured
            )
        if self.chemistry == "sla":
            return replace(pack, capacity_x=self.capacity_x)
        return replace(pack, lithium_x=self.lithium_x, active_material_x=self.active_material_x)


HEALTH_PACKS = [
    # Ageing parameters chosen on this simulator for about 90 % and 75 % of the fresh capacity
    # (LFP: the cell is lithium-limited, so the lithium sets the capacity; the loss of active
    # material adds current density, hence resistance). The measured values are in the bags.
    HealthPack("lfp_fresh", "lfp", 3),
    HealthPack("lfp_aged90", "lfp", 3, 0.90, 1.3, 0.904, 0.95, serial="ROYPOW-12V6AH-SIM-AGED90"),
    HealthPack("lfp_aged75", "lfp", 3, 0.75, 1.7, 0.758, 0.875, serial="ROYPOW-12V6AH-SIM-AGED75"),
    HealthPack("sla_fresh", "sla", 3),
    HealthPack("sla_aged90", "sla", 3, 0.90, 1.3, serial="AJC-12V5AH-SIM-AGED90"),
    HealthPack("sla_aged75", "sla", 3, 0.75, 1.7, serial="AJC-12V5AH-SIM-AGED75"),
    # Other sizes (24 V): 8 LFP cells of 12 Ah, 12 SLA cells of 20 Ah (C/20).
    HealthPack("lfp_24v12ah", "lfp", 2, cells=8, pack_capacity_ah=12.0, serial="LFP-24V12AH-SIM"),
    HealthPack("sla_24v20ah", "sla", 2, cells=12, pack_capacity_ah=20.0, serial="SLA-24V20AH-SIM"),
    # The tuning packs (``*_tuning``): the one place the OCV's ageing law (the battery file's
    # ``health.ocv_ageing_exponent``) and the capacity's prior are chosen; every other pack
    # stays validation. About 82 %, 86 % and 70 % of the fresh capacity, beside the validation
    # packs' 90 % and 75 % (LFP's lithium and active material on the line through theirs).
    HealthPack(
        "lfp_aged82_tuning", "lfp", 3, 0.82, 1.5, 0.825, 0.91, serial="ROYPOW-12V6AH-SIM-AGED82"
    ),
    HealthPack("sla_aged82_tuning", "sla", 3, 0.82, 1.5, serial="AJC-12V5AH-SIM-AGED82"),
    HealthPack(
        "lfp_aged86_tuning", "lfp", 3, 0.86, 1.4, 0.864, 0.93, serial="ROYPOW-12V6AH-SIM-AGED86"
    ),
    HealthPack("sla_aged86_tuning", "sla", 3, 0.86, 1.4, serial="AJC-12V5AH-SIM-AGED86"),
    HealthPack(
        "lfp_aged70_tuning", "lfp", 3, 0.70, 1.9, 0.709, 0.85, serial="ROYPOW-12V6AH-SIM-AGED70"
    ),
    HealthPack("sla_aged70_tuning", "sla", 3, 0.70, 1.9, serial="AJC-12V5AH-SIM-AGED70"),
    # Fresh packs on other robots (sensors), for what a law or a prior costs a new pack.
    HealthPack("lfp_fresh_tuning", "lfp", 3, serial="ROYPOW-12V6AH-SIM-B"),
    HealthPack("sla_fresh_tuning", "sla", 3, serial="AJC-12V5AH-SIM-B"),
]


def pack_resistance_ohm(pack: Pack, capacity_ah: float) -> float:
    """The pack's resistance as :attr:`Pack.resistance_ohm` defines it: from the full state at
    25 degC (isothermal), C/5 to 50 % of ``capacity_ah``, a 1-h rest, then the voltage drop 5 s
    into a 1 C step (of the nominal capacity), per ampere."""
    sim = PackSim(replace(pack, thermal=False), 25.0)
    soc = lambda: 1.0 - sim.discharged_ah / capacity_ah  # noqa: E731
    discharge_to(sim, soc, 0.5, itertools.repeat((30.0, pack.pack_capacity_ah / 5.0)))
    run_segments(sim, [(3600.0, 0.0)], None)
    rested_v = sim.last_v
    run_segments(sim, [(5.0, pack.pack_capacity_ah)], None)
    return (rested_v - sim.last_v) / pack.pack_capacity_ah


def measure_health_pack(hp: HealthPack, fresh: dict | None) -> dict:
    """Age (or size) the pack and measure it: the resistance of its electrochemistry (at 50 %
    of the capacity aimed at), the series resistance that brings it to ``resistance_x`` of the
    fresh pack's (``fresh``: that pack's measurement; None for a fresh or sized pack: no series
    resistance), then the capacity at C/20 (:func:`scenario_capacity_ah`) with it."""
    pack = hp.electrochemistry()
    start = time.monotonic()
    if fresh is None:
        guess_ah = reference_capacity_ah(pack)
        r_chem = pack_resistance_ohm(pack, guess_ah)
        series = 0.0
    else:
        r_chem = pack_resistance_ohm(pack, hp.capacity_x * fresh["capacity_ah"])
        series = hp.resistance_x * fresh["resistance_ohm"] - r_chem
    pack = replace(pack, series_resistance_ohm=series, resistance_ohm=r_chem + series)
    capacity_ah = guess_ah if fresh is None else scenario_capacity_ah(pack)
    ref = fresh or {"capacity_ah": capacity_ah, "resistance_ohm": r_chem + series}
    return {
        "pack": hp.name,
        "chemistry": hp.chemistry,
        "cells_in_series": pack.cells,
        "design_capacity_ah": pack.pack_capacity_ah,
        "serial_number": pack.serial,
        "capacity_ah": round(capacity_ah, 4),
        "capacity_fraction": round(capacity_ah / ref["capacity_ah"], 4),
        "resistance_ohm": round(r_chem + series, 6),
        "resistance_factor": round((r_chem + series) / ref["resistance_ohm"], 4),
        "electrochemical_resistance_ohm": round(r_chem, 6),
        "series_resistance_ohm": round(series, 6),
        "ageing": {
            "capacity_x_aimed": hp.capacity_x,
            "resistance_x_aimed": hp.resistance_x,
            "lithium_x": hp.lithium_x,
            "active_material_x": hp.active_material_x if hp.chemistry == "lfp" else hp.capacity_x,
        },
        "measured_in_s": round(time.monotonic() - start, 1),
    }


def health_pack_measurements(packs: list[HealthPack], out_dir: Path) -> dict[str, dict]:
    """Each pack's measurement (:func:`measure_health_pack`), kept in ``out_dir/packs.yaml`` so
    that a later run (another chemistry, missions left) does not measure it again."""
    path = out_dir / "packs.yaml"
    known = yaml.safe_load(path.read_text()) if path.exists() else {}
    for hp in packs:
        if hp.name in known:
            continue
        fresh = None
        if hp.resistance_x != 1.0 or hp.capacity_x != 1.0:  # aged: of the fresh pack's
            control = next(p for p in HEALTH_PACKS if p.name == f"{hp.chemistry}_fresh")
            if control.name not in known:
                health_pack_measurements([control], out_dir)
                known = yaml.safe_load(path.read_text())
            fresh = known[control.name]
        known[hp.name] = measure_health_pack(hp, fresh)
        m = known[hp.name]
        print(
            f"{hp.name}: {m['capacity_ah']:.4f} Ah (x{m['capacity_fraction']:.4f}), "
            f"{m['resistance_ohm'] * 1000:.2f} mOhm (x{m['resistance_factor']:.3f}), "
            f"{m['measured_in_s']:.0f} s",
            flush=True,
        )
        path.write_text(yaml.safe_dump(known, sort_keys=False))
    return known


def health_pack(hp: HealthPack, m: dict) -> Pack:
    """The measured pack the missions run on (LFP warming, as in the corpus)."""
    return replace(
        hp.electrochemistry(),
        series_resistance_ohm=m["series_resistance_ohm"],
        resistance_ohm=m["resistance_ohm"],
        thermal=hp.chemistry == "lfp",
    )


def simulate_health_mission(hp: HealthPack, k: int, m: dict) -> tuple[dict, dict]:
    """Mission ``k`` of the pack: from the full, rested state (the simulator's full state, as a
    CC-CV charge to its taper and a rest leave it; not recorded), HEALTH_START_REST_S at the
    bridge's current, the seeder's work to half-way (in SoC) to the end, a rest, the work on to
    the pack's SoC limit plus up to HEALTH_END_DSOC, and a rest at the end. Returns the
    signals and the drawn values."""
    seed = hp.seed(k)
    rng = np.random.default_rng([seed, CHEMISTRY_STREAM[hp.chemistry], 0])
    pack = health_pack(hp, m)
    end_soc = round(pack.soc_limit + float(rng.uniform(0.0, HEALTH_END_DSOC)), 4)
    mid_rest_s = on_grid(float(rng.uniform(*HEALTH_REST_S)), HEALTH_RATE_HZ)
    end_rest_s = on_grid(float(rng.uniform(*HEALTH_REST_S)), HEALTH_RATE_HZ)
    mid_soc = 0.5 * (1.0 + end_soc)
    scale = pack.pack_capacity_ah / PACKS[hp.chemistry].pack_capacity_ah
    work = mission(np.random.default_rng([seed, CHEMISTRY_STREAM[hp.chemistry], 1]), pack)
    capacity_ah = m["capacity_ah"]
    sim = PackSim(pack, 25.0)
    soc = lambda: 1.0 - sim.discharged_ah / capacity_ah  # noqa: E731
    rec = Recording()
    rate = HEALTH_RATE_HZ
    run_segments(sim, [(HEALTH_START_REST_S, REST_A)], rec, rate)
    for target, rest_s in ((mid_soc, mid_rest_s), (end_soc, end_rest_s)):
        while soc() > target:
            duration_s, current_a = next(work)
            run_segments(sim, [(on_grid(duration_s, rate), current_a * scale)], rec, rate)
        run_segments(sim, [(rest_s, REST_A)], rec, rate)
    t, i, v, q = rec.arrays()
    temp = rec.temperatures()
    soc_ref = 1.0 - q / capacity_ah
    check_recording(hp.bag_name(k), t, i, v, soc_ref, capacity_ah, None, 1.0 / rate, temp)
    drawn = {
        "end_soc": end_soc,
        "mid_soc": round(mid_soc, 4),
        "mid_rest_s": mid_rest_s,
        "end_rest_s": end_rest_s,
        "current_scale": round(scale, 4),
    }
    data = {"t": t, "i": i, "v": v, "soc": soc_ref, "temp_c": 25.0, "temperature_c": temp}
    return data, drawn


def build_health_mission(hp: HealthPack, k: int, m: dict, out_dir: str) -> dict:
    """Simulate, check and write mission ``k`` of the pack (nothing is written if a check
    fails). The sensors are the pack's robot's (drawn from the pack's first seed, the same in
    each of its missions), their noise the mission's."""
    data, drawn = simulate_health_mission(hp, k, m)
    seed = hp.seed(k)
    pack = health_pack(hp, m)
    sensors = SensorModel.draw(np.random.default_rng([hp.seed(0), CHEMISTRY_STREAM[hp.chemistry]]))
    what = "fresh (the control)" if hp.capacity_x == 1.0 and not hp.sized else "aged"
    if hp.sized:
        what = f"{pack.cells} cells, {pack.pack_capacity_ah:g} Ah nominal"
    description = (
        f"Battery-health mission {k} of {hp.missions} of pack {hp.name} ({what}; {hp.split}, "
        f"seed {seed}): rested at full, the seeder's work to {drawn['mid_soc']:.0%}, a "
        f"{drawn['mid_rest_s'] / 60:.0f}-min rest, the work on to {drawn['end_soc']:.0%}, a "
        f"{drawn['end_rest_s'] / 60:.0f}-min rest; 25 degC, {HEALTH_RATE_HZ:g} Hz."
    )
    spec = BagSpec(hp.bag_name(k), hp.chemistry, "health_mission", seed, description=description)
    extra = {"split": hp.split, "health": {**m, "mission": k, "of": hp.missions, **drawn}}
    return write_bag(
        spec,
        data,
        m["capacity_ah"],
        Path(out_dir),
        pack,
        sensors=sensors,
        rng=np.random.default_rng([seed, CHEMISTRY_STREAM[hp.chemistry], 3]),
        start_ns=EPOCH_NS + seed * 86_400 * 1_000_000_000,
        extra=extra,
    )


def health_readme(meta: dict) -> str:
    """A health mission's README lines: its pack as measured."""
    h = meta["health"]
    return f"""- Pack **{h["pack"]}** ({h["cells_in_series"]} cells in series, design capacity
  {h["design_capacity_ah"]} Ah, serial `{h["serial_number"]}`): capacity measured at C/20
  {h["capacity_ah"]} Ah (x{h["capacity_fraction"]} of the fresh pack), resistance
  {h["resistance_ohm"] * 1000:.2f} mOhm (5 s into 1 C at 50 %; x{h["resistance_factor"]} of the
  fresh pack; {h["series_resistance_ohm"] * 1000:+.2f} mOhm of it in series). Mission {h["mission"]}
  of {h["of"]}, split **validation** (../README.md, "Aged packs and packs of other sizes").
"""


def write_health_status(out_dir: Path, known: dict[str, dict]) -> None:
    """``out_dir/STATUS.md``: the packs as measured and the missions written so far."""
    rows = []
    for hp in HEALTH_PACKS:
        m = known.get(hp.name)
        if m is None:
            continue
        ready = [hp.bag_name(k) for k in range(1, hp.missions + 1)]
        ready = [b for b in ready if (out_dir / b / "bag.yaml").exists()]
        rows.append(
            f"| {hp.name} | {m['cells_in_series']} | {m['design_capacity_ah']} | "
            f"{m['capacity_ah']:.4f} | {m['capacity_fraction']:.4f} | "
            f"{m['resistance_ohm'] * 1000:.2f} | {m['resistance_factor']:.3f} | "
            f"{', '.join(ready) or '-'} |"
        )
    (out_dir / "STATUS.md").write_text(
        "# Battery-health data: packs measured, missions ready\n\n"
        "Written by `tools/make_bags.py --aged/--sized` after each mission. Capacity: C/20 to "
        "the cut-off at 25 degC; resistance: 5 s into a 1 C step at 50 %, rested; fractions "
        "and factors of the chemistry's fresh pack (sized packs: of themselves).\n\n"
        "| Pack | Cells | Design Ah | Capacity Ah | Fraction | R mOhm | R factor | Missions "
        "ready |\n|---|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )


def timed_health_mission(hp: HealthPack, k: int, m: dict, out_dir: str):
    """:func:`build_health_mission`, its failure as a message, its wall time."""
    start = time.monotonic()
    try:
        result: dict | str = build_health_mission(hp, k, m, out_dir)
    except Exception as exc:  # a solver or check failure rejects this one mission
        result = f"{type(exc).__name__}: {exc}"
    return hp, k, result, time.monotonic() - start


def make_health(sized: bool, chemistries: list[str], only, out_dir: Path, jobs: int) -> int:
    """The aged packs' (``sized``: the other sizes') missions not yet in ``out_dir``; rejected
    ones are reported with their seed and not written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    packs = [
        hp
        for hp in HEALTH_PACKS
        if hp.sized == sized and hp.chemistry in chemistries and (not only or hp.name in only)
    ]
    known = health_pack_measurements(packs, out_dir)
    write_health_status(out_dir, known)
    todo = [(hp, k) for hp in packs for k in range(1, hp.missions + 1)]
    todo = [(hp, k) for hp, k in todo if not (out_dir / hp.bag_name(k) / "bag.yaml").exists()]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = [
            pool.submit(timed_health_mission, hp, k, known[hp.name], str(out_dir)) for hp, k in todo
        ]
        for fut in futures:
            hp, k, result, wall_s = fut.result()
            if isinstance(result, str):
                print(f"REJECTED {hp.bag_name(k)} seed {hp.seed(k)}: {result}", flush=True)
                continue
            write_health_status(out_dir, known)
            print(
                f"{result['name']}: {result['duration_s'] / 3600:.2f} h, SoC "
                f"{result['soc_start']:.3f} -> {result['soc_end']:.3f}, {result['samples']} "
                f"samples, {wall_s:.0f} s",
                flush=True,
            )
    return 0


# -- series packs cell by cell (--cells) ----------------------------------------------------
#: The cell-by-cell missions' sample rate (small bags: bags/ has a size cap).
CELLS_RATE_HZ = 1.0
#: Cell-to-cell spread (issue 25): capacity (electrode width) x1 +- 3 %, resistance x1 +- 10 %
#: (a series resistance, ``(x - 1)`` times the cell's share of ``Pack.resistance_ohm``),
#: initial SoC up to 5 % below the fullest cell.
CELLS_CAPACITY_SPREAD = 0.03
CELLS_RESISTANCE_SPREAD = 0.10
CELLS_SOC_SPREAD = 0.05
#: Below this weakest-cell SoC the load is capped (the robot limps home) so that a cell can be
#: driven to its cut-off without the solver's 1.5 V event under a 38 A start-up peak.
CELLS_LIMP_SOC = 0.25
CELLS_LIMP_A = 4.0
#: Every mission starts as the robot boots: the bridge and electronics on, the motors not yet
#: (the node reads its first sample as an OCV).
CELLS_BOOT_S = 30.0


@dataclass(frozen=True)
class CellAdc:
    """A per-cell voltage ADC (a BMS front end as seed 001's LM324 dividers): 12 bits over 5 V
    (1.22 mV steps), gain error and offset per cell, white noise."""

    gain: np.ndarray
    offset_v: np.ndarray
    noise_v: float = 0.001
    step_v: float = 5.0 / 4096.0

    @classmethod
    def draw(cls, rng: np.random.Generator, cells: int) -> CellAdc:
        return cls(rng.uniform(-1e-3, 1e-3, cells), rng.uniform(-2e-3, 2e-3, cells))

    def measure(self, rng: np.random.Generator, cell_v: np.ndarray) -> np.ndarray:
        v = cell_v * (1.0 + self.gain) + self.offset_v
        return quantize(v + rng.normal(0.0, self.noise_v, v.shape), self.step_v)

    def as_dict(self) -> dict:
        return {
            "gain": [round(float(g), 6) for g in self.gain],
            "offset_v": [round(float(o), 6) for o in self.offset_v],
            "noise_v": self.noise_v,
            "step_v": round(self.step_v, 8),
        }


@dataclass(frozen=True)
class CellsSpec:
    name: str
    seed: int
    temp_c: float
    start_soc: float  # the fullest cell's
    stop_soc: float  # the mission ends when the weakest cell's true SoC reaches this
    rest_s: float = 0.0  # a rest half-way down (robot off, bridge on)
    description: str = ""
    chemistry: str = "lfp"  # PACKS' key: lfp, or li_ion (seed 001's 4S LG M50)


#: The mission's currents times this per chemistry: the seeder robot's loads (38 A peaks) are a
#: 6 Ah LFP pack's; a 5 Ah LG M50 pack (7.3 A continuous) gets half of them.
CELLS_LOAD_X = {"lfp": 1.0, "li_ion": 0.5}
#: The cell-by-cell bags' names (``<prefix>_cells_...``) and serial numbers per chemistry.
CELLS_PREFIX = {"lfp": "lfp4s", "li_ion": "li_ion4s"}
CELLS_SERIAL = {"lfp": "ROYPOW-12V6AH-4S-SIM", "li_ion": "LGM50-4S-SIM"}


CELLS_SPECS = [
    CellsSpec(
        "lfp4s_cells_1_full",
        51,
        25.0,
        1.0,
        0.20,
        1200.0,
        "4S LFP pack simulated cell by cell: seeder mission from full (cells spread) with a "
        "20-min stop half-way, down to the weakest cell's 20 %.",
    ),
    CellsSpec(
        "lfp4s_cells_2_partial",
        52,
        25.0,
        0.6,
        0.01,
        0.0,
        "4S LFP pack cell by cell: starts part-charged (the fullest cell 60 %, after a 2-h "
        "rest), seeder mission down to the weakest cell's cut-off (1 % of its charge, or its "
        "voltage collapsing under the load, whichever comes first; the load "
        f"capped at {CELLS_LIMP_A:g} A below {CELLS_LIMP_SOC:.0%}).",
    ),
    CellsSpec(
        "lfp4s_cells_3_cold",
        53,
        5.0,
        0.9,
        0.20,
        0.0,
        "4S LFP pack cell by cell at 5 degC: seeder mission from 90 % (the fullest cell, "
        "after a 2-h rest) down to the weakest cell's 20 %. Not from full: at 1 Hz the cold "
        "pack's voltage on its top knee drifts more in a second than a 0.4 A step moves it, "
        "which check_recording refuses.",
    ),
]


#: The cell-by-cell validation corpus (``--cells --seeds S ...``, outside bags/): missions drawn
#: per seed, none of them seen by the cell filter's settings (chosen on ``lfp4s_cells_1_full``).
#: Ambient 0-35 degC; the fullest cell from full (only at 10 degC or warmer: a colder full
#: start at 1 Hz drifts on its top knee beyond what check_recording accepts), from 90 %, or
#: part-charged 50-85 %; down to the weakest cell's 20 % or its cut-off; half with a stop of
#: 10-40 min half-way.
CELLS_CORPUS_TEMP_C = (0.0, 35.0)
CELLS_CORPUS_PART_SOC = (0.50, 0.85)


def cells_corpus_spec(seed: int, chemistry: str = "lfp") -> CellsSpec:
    """One validation mission of the cell-by-cell corpus, drawn from ``seed``."""
    rng = np.random.default_rng(seed + 7000)
    temp_c = float(round(rng.uniform(*CELLS_CORPUS_TEMP_C), 1))
    kind = str(rng.choice(["full", "ninety", "partial"]))
    if kind == "full" and temp_c < 10.0:
        kind = "ninety"
    start = {"full": 1.0, "ninety": 0.9}.get(
        kind, float(round(rng.uniform(*CELLS_CORPUS_PART_SOC), 3))
    )
    stop = 0.01 if rng.uniform() < 0.5 else 0.20
    rest_s = float(round(rng.uniform(600.0, 2400.0))) if rng.uniform() < 0.5 else 0.0
    return CellsSpec(
        f"{CELLS_PREFIX[chemistry]}_cells_val_{seed}",
        seed,
        temp_c,
        start,
        stop,
        rest_s,
        f"4S {chemistry.upper().replace('_', '-')} pack cell by cell, validation corpus: "
        f"{temp_c:g} degC, the fullest cell from "
        f"{start:.0%}, down to the weakest cell's {'cut-off' if stop < 0.05 else f'{stop:.0%}'}"
        + (f", a {rest_s / 60:.0f}-min stop half-way." if rest_s > 0 else "."),
        chemistry,
    )


def simulate_cells(spec: CellsSpec) -> dict:
    """Each cell its own PyBaMM simulation carrying the same pack current; the pack voltage is
    the sum of the cells'. A cell's reference SoC is over its own capacity (the bundled pack's
    reference capacity times its capacity factor: the corpus measured it within 1 %)."""
    base = PACKS[spec.chemistry]
    n = base.cells
    spread = np.random.default_rng(spec.seed + 500)
    cap_x = 1.0 + spread.uniform(-CELLS_CAPACITY_SPREAD, CELLS_CAPACITY_SPREAD, n)
    res_x = 1.0 + spread.uniform(-CELLS_RESISTANCE_SPREAD, CELLS_RESISTANCE_SPREAD, n)
    soc_off = spread.uniform(0.0, CELLS_SOC_SPREAD, n)
    soc_off[int(spread.integers(n))] = 0.0  # one cell is the fullest
    cell_r_ohm = base.resistance_ohm / n
    packs = [
        replace(
            base,
            cells=1,
            cutoff_v=base.cutoff_v / n,
            capacity_x=float(cap_x[k]),
            series_resistance_ohm=float((res_x[k] - 1.0) * cell_r_ohm),
        )
        for k in range(n)
    ]
    caps = base_capacity_ah(spec.chemistry) * cap_x
    sims = [PackSim(p, spec.temp_c) for p in packs]
    socs = lambda: np.array([1.0 - s.discharged_ah / c for s, c in zip(sims, caps, strict=True)])  # noqa: E731
    c5 = (30.0, base.pack_capacity_ah / 5.0)
    for k, sim in enumerate(sims):  # unrecorded: each cell down to its start, then all rest
        target = spec.start_soc - soc_off[k]
        while 1.0 - sim.discharged_ah / caps[k] > target:
            run_segments(sim, [c5], None)
        run_segments(sim, [(PARK_S, 0.0)], None)
    rng = np.random.default_rng(spec.seed)
    work = mission(rng, base)
    recs = [Recording() for _ in sims]
    rate = CELLS_RATE_HZ
    half = spec.start_soc - 0.5 * (spec.start_soc - spec.stop_soc)
    rested = spec.rest_s <= 0.0
    for sim, rec in zip(sims, recs, strict=True):
        run_segments(sim, [(CELLS_BOOT_S, ELECTRONICS_A * CELLS_LOAD_X[spec.chemistry])], rec, rate)
    while float(np.min(socs())) > spec.stop_soc:
        duration_s, current_a = next(work)
        current_a *= CELLS_LOAD_X[spec.chemistry]
        if float(np.min(socs())) < CELLS_LIMP_SOC:
            current_a = min(current_a, CELLS_LIMP_A)
        segs = [(on_grid(duration_s, rate), current_a)]
        if not rested and float(np.min(socs())) <= half:
            segs.append((on_grid(spec.rest_s, rate), REST_A))
            rested = True
        parts = [Recording() for _ in sims]
        try:
            for sim, part in zip(sims, parts, strict=True):
                run_segments(sim, segs, part, rate)
        except RuntimeError:  # a cell collapsed under the load: its cut-off, the mission's end
            break
        for rec, part in zip(recs, parts, strict=True):
            for field_name in ("t_s", "current_a", "voltage_v", "discharged_ah", "temperature_c"):
                getattr(rec, field_name).extend(getattr(part, field_name))
    arrays = [rec.arrays() for rec in recs]
    t, i = arrays[0][0], arrays[0][1]
    cell_v = np.stack([a[2] for a in arrays], axis=1)
    cell_soc = np.stack([1.0 - a[3] / c for a, c in zip(arrays, caps, strict=True)], axis=1)
    # Each cell's reference against its own charge; the voltage checks on the pack's voltage
    # (a lone cell on its knee drifts more in a second than a 0.3 A step moves it).
    for k in range(n):
        check_recording(
            f"{spec.name} cell {k + 1}",
            t,
            i,
            cell_v.sum(axis=1),
            cell_soc[:, k],
            caps[k],
            None,
            1 / rate,
        )
    return {
        "t": t,
        "i": i,
        "v": cell_v.sum(axis=1),
        "cell_v": cell_v,
        "cell_soc": cell_soc,
        "capacity_ah": caps,
        "capacity_x": cap_x,
        "resistance_x": res_x,
        "soc_offset": soc_off,
    }


def usable_soc(cell_soc: np.ndarray, capacity_ah: np.ndarray, pack_capacity_ah: float):
    """The pack's usable discharge SoC: the weakest cell's remaining charge over the pack's
    capacity, ``min_i SoC_i Q_i / Q``."""
    return np.min(cell_soc * capacity_ah, axis=1) / pack_capacity_ah


def build_cells(spec: CellsSpec, out_dir: str) -> dict:
    """Simulate, check and write one cell-by-cell mission; its reference SoC is the usable one
    over the bundled pack's reference capacity, ``/battery/cell_soc_reference`` every cell's."""
    data = simulate_cells(spec)
    base = PACKS[spec.chemistry]
    cap = base_capacity_ah(spec.chemistry)
    rng = np.random.default_rng(spec.seed + 1000)
    sensors = SensorModel.draw(rng)
    adc = CellAdc.draw(rng, base.cells)
    t, i, v = data["t"], data["i"], data["v"]
    temp = np.full(t.size, spec.temp_c)
    i_m, v_m, temp_m = sensors.measure(rng, i, v, temp)
    cell_m = adc.measure(rng, data["cell_v"])
    soc = usable_soc(data["cell_soc"], data["capacity_ah"], cap)
    start_ns = EPOCH_NS + spec.seed * 86_400 * 1_000_000_000
    stamps = start_ns + np.round(t * 1e9).astype(np.int64)
    state = [
        (
            int(s),
            battery_state_message(
                bridge_state(
                    int(s),
                    float(vm),
                    float(im),
                    temperature_c=float(tm),
                    design_capacity_ah=base.pack_capacity_ah,
                    technology=base.technology,
                    location="seeder_robot",
                    serial_number=CELLS_SERIAL[spec.chemistry],
                ),
                cm,
            ),
        )
        for s, vm, im, tm, cm in zip(stamps, v_m, i_m, temp_m, cell_m, strict=True)
    ]
    reference = [
        (
            int(s),
            battery_state_message(
                bridge_state(
                    int(s),
                    float(vt),
                    float(it),
                    temperature_c=spec.temp_c,
                    percentage=float(sc),
                    charge_ah=float(sc * cap),
                    capacity_ah=cap,
                    design_capacity_ah=base.pack_capacity_ah,
                    technology=base.technology,
                    location="simulator_truth",
                    serial_number=CELLS_SERIAL[spec.chemistry],
                ),
                cv,
            ),
        )
        for s, vt, it, sc, cv in zip(stamps, v, i, soc, data["cell_v"], strict=True)
    ]
    label = "fields:" + ",".join(f"cell_soc_{k + 1}" for k in range(base.cells))
    cells = [
        (int(s), float64_array_message(label, row))
        for s, row in zip(stamps, data["cell_soc"], strict=True)
    ]
    bag = Path(out_dir) / spec.name
    if bag.exists():
        shutil.rmtree(bag)
    write_rosbag(
        bag,
        [
            (STATE_TOPIC, BATTERY_STATE, state),
            (REFERENCE_TOPIC, BATTERY_STATE, reference),
            (CELL_REFERENCE_TOPIC, FLOAT64_ARRAY, cells),
        ],
        storage="mcap",
        compression="chunk",
    )
    # The first cell's cut-off: the mission's end when it ran the weakest cell empty.
    cut_s = round(float(t[-1] - t[0]), 1) if spec.stop_soc < 0.05 else None
    meta = {
        "name": spec.name,
        "chemistry": spec.chemistry,
        "kind": "cells_mission",
        "storage": "mcap",
        "seed": spec.seed,
        "ambient_temperature_c": spec.temp_c,
        "duration_s": round(float(t[-1] - t[0]), 1),
        "samples": int(t.size),
        "sample_rate_hz": CELLS_RATE_HZ,
        "soc_start": round(float(soc[0]), 4),
        "soc_end": round(float(soc[-1]), 4),
        "reference_capacity_ah": round(cap, 4),
        "current_max_a": round(float(np.max(i)), 2),
        "current_min_a": round(float(np.min(i)), 2),
        "sensors": sensors.as_dict(),
        "cell_adc": adc.as_dict(),
        "cells": {
            "capacity_x": [round(float(x), 4) for x in data["capacity_x"]],
            "capacity_ah": [round(float(x), 4) for x in data["capacity_ah"]],
            "resistance_x": [round(float(x), 4) for x in data["resistance_x"]],
            "initial_soc_offset": [round(float(x), 4) for x in data["soc_offset"]],
            "soc_start": [round(float(x), 4) for x in data["cell_soc"][0]],
            "soc_end": [round(float(x), 4) for x in data["cell_soc"][-1]],
            "weakest_at_end": int(np.argmin(data["cell_soc"][-1] * data["capacity_ah"])) + 1,
            "first_cutoff_s": cut_s,
        },
        "description": spec.description,
    }
    (bag / "bag.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    (bag / "README.md").write_text(
        bag_readme(meta)
        + f"""- Cells (in series order): capacity x{meta["cells"]["capacity_x"]}, resistance
  x{meta["cells"]["resistance_x"]}, SoC {meta["cells"]["soc_start"]} ->
  {meta["cells"]["soc_end"]}; per-cell ADC (`cell_voltage`): 12 bits over 5 V, noise 1 mV,
  gain and offset in bag.yaml `cell_adc`.
- `/battery/soc_reference` is the usable SoC (the weakest cell's remaining charge over
  {cap:.4f} Ah); its `cell_voltage` the true cell voltages; `/battery/cell_soc_reference`
  every cell's true SoC (over the cell's own capacity).
"""
    )
    return meta


def make_cells(
    only, out_dir: Path, jobs: int, seeds: list[int] | None = None, chemistry: str = "lfp"
) -> int:
    if seeds:
        if out_dir.resolve() == (ROOT / "bags").resolve():
            raise SystemExit(
                "the cells corpus is not bundled: give --out a directory outside bags/"
            )
        specs = [cells_corpus_spec(s, chemistry) for s in seeds]
    else:
        specs = [s for s in CELLS_SPECS if not only or s.name in only]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for m in pool.map(build_cells, specs, itertools.repeat(str(out_dir))):
            print(
                f"{m['name']}: {m['duration_s'] / 3600:.2f} h, usable SoC {m['soc_start']:.3f} -> "
                f"{m['soc_end']:.3f}, weakest cell {m['cells']['weakest_at_end']}, "
                f"{m['samples']} samples"
            )
    return 0


# -- OCV hysteresis (--hysteresis) -----------------------------------------------------------
#: The hysteretic LFP pack: the bundled LFP pack (SPMe, Prada2013, 4S, 6 Ah) with PyBaMM's
#: one-state OCP hysteresis on its LFP electrode (:data:`HYSTERESIS_OCP_OPTION`), 16 mV per
#: cell; a serial of its own (another pack for the node).
HYSTERESIS_PACK = replace(
    PACKS["lfp"],
    serial="ROYPOW-12V6AH-SIM-HYST",
    ocp_hysteresis_v=LFP_HYSTERESIS_GAP_V,
    hysteresis_decay_soc=LFP_HYSTERESIS_DECAY_SOC,
)
#: The test's reversal steps after each direction: 2, 3 and 5 % of the nominal capacity (10 %
#: in all, one 0.2 C pulse), each with a 1-h rest: they trace the branch change.
HYSTERESIS_SMALL_STEPS = (0.02, 0.03, 0.05)
#: The test's 0.2 C pulses of 10 %: down from full to ~28 %, and up again to ~79 %.
HYSTERESIS_DOWN_PULSES = 7
HYSTERESIS_UP_PULSES = 4
#: The test's samples: HYSTERESIS_HEAD_S at its spec's rate from each segment's start (the
#: voltage's answer to each step and its first relaxation), the spec's tail rate after it.
HYSTERESIS_HEAD_S = 300.0
#: The validation run's long rests (:func:`hysteresis_long_rests`): each rest 6 h, not 1 h.
HYSTERESIS_LONG_REST_S = 6 * 3600.0


def hysteresis_test_segments(pack: Pack) -> tuple[list[tuple[float, float]], list[str]]:
    """A two-direction pulse test: 10 min rest at full; 0.2 C (10 %) 30-min discharge pulses
    with 1-h rests down to ~28 % (``down``); a reversal, charges of 2, 3 and 5 % with 1-h rests
    (``up_small``: the branch change from discharge to charge); 10 % charges with 1-h rests up
    to ~79 % (``up``); a reversal back, discharges of 2, 3 and 5 % with 1-h rests
    (``back_small``). Returns the segments and each rest's label (``start`` for the first)."""
    current = 0.2 * pack.pack_capacity_ah  # 10 % of the nominal capacity in 30 min
    segs: list[tuple[float, float]] = [(600.0, 0.0)]
    labels = ["start"]

    def pulse(fraction: float, sign: float, label: str) -> None:
        segs.extend([(fraction / 0.2 * 3600.0, sign * current), (3600.0, 0.0)])
        labels.append(label)

    for _ in range(HYSTERESIS_DOWN_PULSES):
        pulse(0.1, 1.0, "down")
    for f in HYSTERESIS_SMALL_STEPS:
        pulse(f, -1.0, "up_small")
    for _ in range(HYSTERESIS_UP_PULSES):
        pulse(0.1, -1.0, "up")
    for f in HYSTERESIS_SMALL_STEPS:
        pulse(f, 1.0, "back_small")
    return segs, labels


def hysteresis_branches(labels: list[str], ends: list[int]) -> list[list[int]]:
    """The test's rest ends grouped so that, in each group, the SoC falls: the way down (the
    discharge branch, the rest at full first), the way up read backwards (the charge branch
    down to the reversal, then the branch change down to the last rest of the way down), and
    the way back (the last rest up, then the branch change back)."""
    down = [e for e, lab in zip(ends, labels, strict=True) if lab in ("start", "down")]
    up = [e for e, lab in zip(ends, labels, strict=True) if lab in ("up_small", "up")]
    back = [e for e, lab in zip(ends, labels, strict=True) if lab == "back_small"]
    return [down, (down[-1:] + up)[::-1], up[-1:] + back]


def hysteresis_pairs(rests: list[dict], key: str) -> list[dict]:
    """Rest voltages after a charge and after a discharge at the same counted SoC (within 0.1 %
    of the reference capacity): the charge branch's rests against the way down's."""
    down = [r for r in rests if r["label"] in ("start", "down")]
    pairs = []
    for r in rests:
        if r["label"] not in ("up_small", "up"):
            continue
        match = [d for d in down if abs(d["soc"] - r["soc"]) < 1e-3]
        if match:
            d = match[0]
            pairs.append(
                {
                    "soc": round(r["soc"], 4),
                    "after_charge_v": round(r[key], 4),
                    "after_discharge_v": round(d[key], 4),
                    "gap_v": round(r[key] - d[key], 4),
                }
            )
    return pairs


def hysteresis_meta(pack: Pack) -> dict:
    """The pack's true hysteresis parameters, for bag.yaml (``hysteresis``)."""
    import pybamm

    pv = pybamm.ParameterValues(pack.parameter_set)
    q_p_ah = positive_electrode_capacity_ah(pv)
    return {
        "model": "PyBaMM SPMe, 'open-circuit potential': "
        f"{list(HYSTERESIS_OCP_OPTION)} (one-state hysteresis, Axen2022) on the positive (LFP) "
        "electrode; the graphite without",
        "gap_per_cell_v": pack.ocp_hysteresis_v,
        "gap_pack_v": round(pack.ocp_hysteresis_v * pack.cells, 6),
        "lithiation_ocp": f"Prada2013 LFP OCP - {pack.ocp_hysteresis_v / 2:g} V (discharge)",
        "delithiation_ocp": f"Prada2013 LFP OCP + {pack.ocp_hysteresis_v / 2:g} V (charge)",
        "decay_rate": round(hysteresis_decay_rate(pv, pack), 4),
        "decay_rate_unit": "per unit of the LFP stoichiometry, both directions",
        "decay_soc_of_nominal": pack.hysteresis_decay_soc,
        "positive_electrode_capacity_ah": round(q_p_ah, 4),
        "state_at_full": 1.0,
        "state_meaning": "+1 the charge (delithiation) branch, -1 the discharge (lithiation) "
        "branch; the simulator's full state (as a charge leaves it, before any unrecorded start) "
        "is +1",
        "pybamm": pybamm.__version__,
    }


def simulate_hysteresis_test(spec: BagSpec, capacity_ah: float, pack: Pack) -> dict:
    """:func:`hysteresis_test_segments` on the hysteretic pack, checked per branch: the rest
    voltages fall with the SoC on each (``check_recording``), and after a charge the rest is
    above the rest after a discharge at the same SoC by at least half the pack's gap."""
    sim = PackSim(pack, spec.temp_c)
    rec = Recording()
    segs, labels = hysteresis_test_segments(pack)
    run_segments(sim, segs, rec, spec.rate_hz, spec.tail_rate_hz, HYSTERESIS_HEAD_S)
    counts = np.cumsum([x.size for x in rec.t_s])
    ends = [int(counts[0]) - 1] + [int(counts[k]) - 1 for k in range(2, len(segs), 2)]
    t, i, v, q = rec.arrays()
    soc_ref = 1.0 - q / capacity_ah
    h = np.concatenate(sim.h_samples)
    check_recording(spec.name, t, i, v, soc_ref, capacity_ah, hysteresis_branches(labels, ends))
    rests = [
        {
            "label": lab,
            "soc": float(soc_ref[e]),
            "v_1h": float(v[e]),
            "state": float(h[e]),
        }
        for lab, e in zip(labels, ends, strict=True)
    ]
    pairs = hysteresis_pairs(rests, "v_1h")
    gap = pack.ocp_hysteresis_v * pack.cells
    if len(pairs) != HYSTERESIS_UP_PULSES + 1 or min(p["gap_v"] for p in pairs) < 0.5 * gap:
        raise RuntimeError(f"{spec.name}: rests after a charge not above those after a discharge")
    table = [
        {
            "label": r["label"],
            "soc": round(r["soc"], 4),
            "v": round(r["v_1h"], 4),
            "state": round(r["state"], 4),
        }
        for r in rests
    ]
    return {
        "t": t,
        "i": i,
        "v": v,
        "soc": soc_ref,
        "temp_c": spec.temp_c,
        "rests": table,
        "pairs_1h": pairs,
    }


def hysteresis_long_rests(pack: Pack, capacity_ah: float) -> list[dict]:
    """Validation (not a bag): the hysteresis test with every rest HYSTERESIS_LONG_REST_S long;
    the rest voltages after a charge and after a discharge at the same SoC, after 1 h and at
    the end of the long rest."""
    sim = PackSim(pack, 25.0)
    segs, labels = hysteresis_test_segments(pack)
    rests = []
    run_segments(sim, segs[:1], None)
    rests.append({"label": labels[0], "soc": 1.0, "v_1h": sim.last_v, "v_long": sim.last_v})
    for k in range(1, len(segs), 2):
        run_segments(sim, [segs[k], (3600.0, 0.0)], None)
        v_1h = sim.last_v
        run_segments(sim, [(HYSTERESIS_LONG_REST_S - 3600.0, 0.0)], None)
        soc = 1.0 - sim.discharged_ah / capacity_ah
        label = labels[(k + 1) // 2]
        rests.append({"label": label, "soc": soc, "v_1h": v_1h, "v_long": sim.last_v})
    return hysteresis_pairs(rests, "v_long")


HYSTERESIS_TEST = BagSpec(
    "lfp_hysteresis_test",
    "lfp",
    "hysteresis_test",
    41,
    description="Two-direction pulse test on the hysteretic LFP pack (PyBaMM one-state OCP "
    "hysteresis, 16 mV per cell; bags/README.md, 'Hysteresis'): 10 min rest at full; seven "
    "0.2 C (1.2 A) 30-min discharge pulses (10 % each) with 1-h rests, 100 % to 28 %; charges "
    "of 2, 3 and 5 % with 1-h rests (the branch change); four 10 % charges with 1-h rests to "
    "79 %; discharges of 2, 3 and 5 % with 1-h rests, to 69 %. 1 Hz, 0.05 Hz past each "
    "segment's first 5 minutes (bags/ stays under 80 MB).",
    rate_hz=1.0,
    tail_rate_hz=0.05,
)


def _hysteresis_scenario(seed: int, **values) -> Scenario:
    """A hand-made corpus-style mission (seeder profile, 2 Hz, the bundled pack's size and
    resistance), its sensors drawn in the bundled bags' ranges."""
    sensors = SensorModel.draw(np.random.default_rng([seed, CHEMISTRY_STREAM["lfp"], 0]))
    base = {
        "chemistry": "lfp",
        "seed": seed,
        "profile": "seeder",
        "slopes": False,
        "sample_rate_hz": 2.0,
        "capacity_x": 1.0,
        "resistance_x": 1.0,
        "rests": (),
        "opportunity_charges": (),
        "charge_c": 0.5,
        "dock_soc": None,
        "sensors": sensors,
    }
    return Scenario(**{**base, **values})


#: Seeder missions on the hysteretic pack (seeds 3001-3005, odd: validation), each a
#: corpus-style :class:`Scenario` run by :func:`simulate_mission` (the lumped thermal model).
#: Fractions of the work place the rests and charges (tuned on the mission as simulated).
HYSTERESIS_MISSIONS = [
    (
        "lfp_hysteresis_mission_1_dock",
        _hysteresis_scenario(
            3001,
            ambient_c=25.0,
            start_soc=0.6,
            start_rested=True,
            work_s=4800.0,
            rests=((0.25, 900.0), (0.47, 1200.0), (0.98, 1200.0)),
            dock_soc=0.3,
        ),
        "Hysteresis mission (validation, seed 3001) on the hysteretic LFP pack: starts at 60 % "
        "rested on the discharge branch (driven down at C/5, parked 2 h), seeder work with a "
        "15-min stop at ~43 %, a dock CC-CV charge to full at 30 % (0.5 C), work again: a "
        "20-min stop 2 % below full (the branch change under way), the work on to ~45 %, a "
        "20-min stop. 25 degC, lumped thermal model, 2 Hz.",
    ),
    (
        "lfp_hysteresis_mission_2_opportunity",
        _hysteresis_scenario(
            3003,
            ambient_c=25.0,
            start_soc=0.7,
            start_rested=True,
            work_s=3300.0,
            rests=((0.3, 900.0), (0.3002, 900.0), (0.75, 900.0), (0.98, 900.0)),
            opportunity_charges=((0.3001, 900.0),),
        ),
        "Hysteresis mission (validation, seed 3003) on the hysteretic LFP pack: starts at 70 % "
        "rested on the discharge branch, seeder work to ~57 %, a 15-min stop, a 15-min "
        "opportunity charge at 0.5 C on the plateau (to ~69 %), a 15-min stop on the charge "
        "branch, the work on with a 15-min stop at ~47 % and one at the end (~35 %). 25 degC, "
        "lumped thermal model, 2 Hz.",
    ),
    (
        "lfp_hysteresis_mission_3_cold",
        _hysteresis_scenario(
            3005,
            ambient_c=5.0,
            start_soc=1.0,
            start_rested=True,
            work_s=5400.0,
            rests=((0.04, 1200.0), (0.45, 1200.0), (0.6502, 1200.0)),
            opportunity_charges=((0.65, 600.0),),
            dock_soc=0.25,
            charge_c=0.3,
        ),
        "Hysteresis mission (validation, seed 3005) on the hysteretic LFP pack, cold: 5 degC, "
        "starts full and rested (the charge branch), a 20-min stop 3 % below full, work to "
        "~66 % and a 20-min stop, work to ~49 %, a 10-min opportunity charge at 0.3 C (to "
        "~54 %) and a 20-min stop after it, the work on, a dock CC-CV charge to full at 25 % "
        "(0.3 C), work again to ~94 %. Lumped thermal model, 2 Hz.",
    ),
]
#: Bundled in bags/ (the rest into a directory of your own): bags/ stays under 80 MB.
HYSTERESIS_BUNDLED = ("lfp_hysteresis_test",)


def build_hysteresis_test(capacity_ah: float, out_dir: str) -> dict:
    """Simulate, check and write the hysteresis test; its rests, the matched pairs (1 h and
    6 h, :func:`hysteresis_long_rests`) and the pack's hysteresis go into bag.yaml."""
    spec, pack = HYSTERESIS_TEST, HYSTERESIS_PACK
    data = simulate_hysteresis_test(spec, capacity_ah, pack)
    extra = {
        "hysteresis": {
            **hysteresis_meta(pack),
            "rests": data["rests"],
            "pairs_1h": data["pairs_1h"],
            "pairs_6h_validation": hysteresis_long_rests(pack, capacity_ah),
        }
    }
    return write_bag(
        spec,
        data,
        capacity_ah,
        Path(out_dir),
        pack,
        start_ns=EPOCH_NS + spec.seed * 86_400 * 1_000_000_000,
        extra=extra,
    )


def build_hysteresis_mission(
    name: str, sc: Scenario, description: str, capacity_ah: float, out_dir: str
) -> dict:
    """Simulate, check and write one hysteresis mission (``kind: mission``, as the corpus's)."""
    pack = replace(HYSTERESIS_PACK, thermal=True)  # the corpus's LFP missions' lumped model
    data = simulate_mission(sc, pack, capacity_ah)
    spec = BagSpec(name, "lfp", "mission", sc.seed, sc.ambient_c, description=description)
    ratio = capacity_ah / base_capacity_ah("lfp")
    return write_mission(sc, spec, pack, data, capacity_ah, ratio, out_dir)


def _timed(fn, *args) -> tuple[dict | str, float]:
    start = time.monotonic()
    try:
        result: dict | str = fn(*args)
    except Exception as exc:  # a failed check rejects this one bag
        result = f"{type(exc).__name__}: {exc}"
    return result, time.monotonic() - start


def make_hysteresis(only, out_dir: Path, jobs: int) -> int:
    """The hysteresis test and missions (``--only`` some); into bags/ only the bundled ones."""
    names = [HYSTERESIS_TEST.name] + [m[0] for m in HYSTERESIS_MISSIONS]
    if out_dir.resolve() == (ROOT / "bags").resolve():
        names = [n for n in names if n in HYSTERESIS_BUNDLED]
    names = [n for n in names if not only or n in only]
    out_dir.mkdir(parents=True, exist_ok=True)
    capacity_ah = reference_capacity_ah(HYSTERESIS_PACK)
    print(f"lfp hysteresis: reference capacity {capacity_ah:.4f} Ah (C/20 to cut-off, 25 degC)")
    failed = 0
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = []
        if HYSTERESIS_TEST.name in names:
            futures.append(pool.submit(_timed, build_hysteresis_test, capacity_ah, str(out_dir)))
        for name, sc, description in HYSTERESIS_MISSIONS:
            if name in names:
                args = (name, sc, description, capacity_ah, str(out_dir))
                futures.append(pool.submit(_timed, build_hysteresis_mission, *args))
        for fut in futures:
            m, wall_s = fut.result()
            if isinstance(m, str):
                print(f"REJECTED: {m}", flush=True)
                failed += 1
                continue
            print(
                f"{m['name']}: {m['duration_s'] / 3600:.2f} h, SoC {m['soc_start']:.3f} -> "
                f"{m['soc_end']:.3f}, {m['samples']} samples, {wall_s:.0f} s",
                flush=True,
            )
            hy = m["hysteresis"]
            for key in ("pairs_1h", "pairs_6h_validation"):
                for p in hy.get(key, []):
                    print(
                        f"  {key} SoC {p['soc']:.3f}: after charge {p['after_charge_v']:.4f} V, "
                        f"after discharge {p['after_discharge_v']:.4f} V, "
                        f"gap {p['gap_v'] * 1000:.1f} mV"
                    )
    return 1 if failed else 0


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
    ap.add_argument(
        "--corpus", action="store_true", help="make scenario-corpus missions (Scenario corpus)"
    )
    ap.add_argument(
        "--aged", action="store_true", help="make the aged packs' missions (Aged packs ...)"
    )
    ap.add_argument(
        "--sized", action="store_true", help="make the missions of packs of other sizes"
    )
    ap.add_argument(
        "--cells", action="store_true", help="make the 4S LFP cell-by-cell missions (--cells)"
    )
    ap.add_argument(
        "--hysteresis",
        action="store_true",
        help="make the hysteretic LFP pack's test and missions (Hysteresis)",
    )
    ap.add_argument("--count", type=int, default=30, help="corpus: missions per chemistry")
    ap.add_argument("--chemistry", nargs="+", choices=sorted(PACKS), default=["lfp", "sla"])
    ap.add_argument("--seeds", type=int, nargs="+", help="corpus: these seeds, not --count")
    args = ap.parse_args(argv)
    if "li_ion" in args.chemistry and not args.cells:
        ap.error("--chemistry li_ion: its cell-by-cell missions only (--cells --seeds)")
    if args.corpus:
        seeds = args.seeds or range(CORPUS_FIRST_SEED, CORPUS_FIRST_SEED + args.count)
        return make_corpus(args.chemistry, list(seeds), args.out, args.jobs, args.hysteresis)
    if args.cells:
        chems = [c for c in args.chemistry if c in CELLS_PREFIX]
        if len(chems) != 1 or (chems != ["lfp"] and not args.seeds):
            ap.error("--cells: one --chemistry of lfp (default) or li_ion (with --seeds)")
        return make_cells(args.only, args.out, args.jobs, args.seeds, chems[0])
    if args.hysteresis:
        return make_hysteresis(args.only, args.out, args.jobs)
    if args.aged or args.sized:
        return make_health(args.sized, args.chemistry, args.only, args.out, args.jobs)
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
