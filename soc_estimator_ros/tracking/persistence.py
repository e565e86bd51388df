"""Saving and restoring a tracker's SoC across restarts (no ROS).

The state file is a small YAML mapping::

    format: 1
    soc: 0.7312            # fraction
    soc_var: 1.2e-05       # fraction^2
    stamp_s: 1778152330.1  # header stamp of the last accepted sample (s, ROS time)
    estimator: hybrid
    battery: AJC 12 V 5 Ah SLA (seed 000)
    health:                # optional: what health/ learned of this pack (HealthState)
      capacity_ah: 4.71
      capacity_var_ah2: 0.0049
      r0_factor: 1.32
      r0_factor_var: 0.0025
      serial_number: SLA-0042
      stamp_s: 1778152330.1
      current_a: 0.35
    cells:                 # optional: the cells' deviation filters (cells/filter.py)
      x: [[0.012, 0.0, 0.0004], ...]          # per cell: d_soc, d_capacity, d_r_ohm
      p: [[[1.0e-05, 0.0, 0.0], ...], ...]    # per cell: their 3 x 3 covariance
    hysteresis:            # optional: the OCV hysteresis' state (models/hysteresis.py)
      branch: 1.0          # 0 on the discharge branch, 1 on the charge branch
      var: 0.0

The cells are resumed with the SoC (within ``resume_max_age_s``, for a pack of as many
cells), their deviations' variance grown by the filter's random walk over the time between
(``CellDeltaFilter.start_from``): after a restart the weakest cell is still known, instead
of every cell starting again from its prior until the next long rest.

:func:`save_state` writes it atomically: a temporary file in the same directory is written,
flushed and ``fsync``-ed, then ``os.replace``-d over the old file, and the directory is
``fsync``-ed, so a power cut leaves either the old or the new file, never a torn one.

:func:`load_state` validates every field (:class:`StateFileError` names the file and the
problem). :func:`resume_decision` says whether a saved state may be resumed from at a given
time: only when it exists, is valid, belongs to the same battery and is younger than
``resume_max_age_s``; otherwise it returns the reason, which the node logs before it falls back
to an OCV initialization. The health is long-lived: :func:`resume_health` takes it from a file
of the same battery whatever its age (a pack keeps its capacity over a week in the shed; its
SoC may not). A file that exists but cannot be used is set aside
(:func:`set_aside`: renamed ``<name>.unusable``) so the next start does not meet it again, and
temporary files a kill left behind during a save are removed at start
(:func:`remove_stale_temp_files`).
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import SocEstimatorError
from ..health import HealthState
from ..models.hysteresis import HysteresisState
from ..units import MAX_SOC_VAR

FORMAT_VERSION = 1


class StateFileError(SocEstimatorError, ValueError):
    """A state file that cannot be used, with its path and the problem."""

    def __init__(self, path: Path | str, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = Path(path)
        self.problem = problem


@dataclass(frozen=True)
class CellsState:
    """The cells' deviation filters (``cells/filter.py``): for each cell its state ``x``
    (``d_soc``, ``d_capacity``, ``d_r_ohm``) and covariance ``p`` (3 x 3)."""

    x: tuple[tuple[float, ...], ...]
    p: tuple[tuple[tuple[float, ...], ...], ...]

    @classmethod
    def of_arrays(cls, x: np.ndarray, p: np.ndarray) -> CellsState:
        """From the filter's arrays, (N, 3) and (N, 3, 3)."""
        return cls(
            tuple(tuple(float(v) for v in row) for row in x),
            tuple(tuple(tuple(float(v) for v in row) for row in cell) for cell in p),
        )

    @property
    def cells(self) -> int:
        return len(self.x)


@dataclass(frozen=True)
class SavedState:
    """What is saved: the SoC, its variance, when, by which estimator, for which battery.

    Attributes:
        soc: SoC fraction in [0, 1].
        soc_var: SoC variance (fraction^2, > 0).
        stamp_s: header stamp of the last sample behind the estimate (s).
        estimator: estimator name.
        battery: battery name (``BatteryParams.name``).
        health: what the health monitor learned (None: health learning off).
        cells: the cells' deviations from the pack (None: no cell voltages in the input).
        hysteresis: where the pack is between its OCV branches (None: a battery without
            hysteresis).
    """

    soc: float
    soc_var: float
    stamp_s: float
    estimator: str
    battery: str
    health: HealthState | None = None
    cells: CellsState | None = None
    hysteresis: HysteresisState | None = None

    def as_dict(self) -> dict[str, Any]:
        """The YAML mapping written to the file."""
        out: dict[str, Any] = {
            "format": FORMAT_VERSION,
            "soc": float(self.soc),
            "soc_var": float(self.soc_var),
            "stamp_s": float(self.stamp_s),
            "estimator": str(self.estimator),
            "battery": str(self.battery),
        }
        if self.health is not None:
            h = self.health
            out["health"] = {
                **{k: float(getattr(h, k)) for k in _HEALTH_NUMBERS},
                "serial_number": str(h.serial_number),
            }
        if self.cells is not None:
            out["cells"] = {
                "x": [list(row) for row in self.cells.x],
                "p": [[list(row) for row in cell] for cell in self.cells.p],
            }
        if self.hysteresis is not None:
            out["hysteresis"] = {
                "branch": float(self.hysteresis.branch),
                "var": float(self.hysteresis.var),
            }
        return out


#: The numbers of a saved :class:`HealthState` (NaN allowed only for the last sample's).
_HEALTH_NUMBERS = (
    "capacity_ah",
    "capacity_var_ah2",
    "r0_factor",
    "r0_factor_var",
    "stamp_s",
    "current_a",
)


def _fsync_dir(directory: Path) -> None:
    """fsync a directory so a rename in it is durable (no-op where unsupported)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _temp_prefix(path: Path) -> str:
    return f".{path.name}."


def remove_stale_temp_files(path: Path | str) -> list[Path]:
    """Remove the temporary files a kill during :func:`save_state` left beside ``path``.

    Only one writer owns a state file, so at its start every such file is stale. Returns the
    files removed (those that could not be are left, silently: they are harmless).
    """
    p = Path(path).expanduser()
    removed: list[Path] = []
    if not p.parent.is_dir():
        return removed
    for tmp in p.parent.glob(_temp_prefix(p) + "*.tmp"):
        with contextlib.suppress(OSError):
            tmp.unlink()
            removed.append(tmp)
    return removed


def set_aside(path: Path | str) -> Path | None:
    """Rename an unusable state file to ``<name>.unusable`` (replacing an older one); returns
    the new path, or None when the file is absent or cannot be renamed."""
    p = Path(path).expanduser()
    if not p.exists():
        return None
    target = p.with_name(p.name + ".unusable")
    try:
        os.replace(p, target)
    except OSError:
        return None
    return target


def save_state(path: Path | str, state: SavedState) -> None:
    """Write ``state`` to ``path`` atomically (creates the directory); ``OSError`` on failure."""
    p = Path(path).expanduser()
    p.parent.mkdir(parents=True, exist_ok=True)
    text = "# soc_estimator_ros state (tracking/persistence.py); safe to delete\n" + yaml.safe_dump(
        state.as_dict(), sort_keys=False
    )
    fd, tmp_name = tempfile.mkstemp(prefix=_temp_prefix(p), suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp_name, p)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp_name)
        raise
    _fsync_dir(p.parent)


def _number(path: Path, raw: dict[str, Any], key: str) -> float:
    value = raw.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise StateFileError(path, f"{key} = {value!r}: expected a number")
    if not math.isfinite(float(value)):
        raise StateFileError(path, f"{key} = {value!r}: expected a finite number")
    return float(value)


def _health(path: Path, raw: Any) -> HealthState:
    """The ``health`` mapping of a state file, validated."""
    if not isinstance(raw, dict):
        raise StateFileError(path, "health: expected a mapping")
    values: dict[str, float] = {}
    for key in _HEALTH_NUMBERS:
        value = raw.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise StateFileError(path, f"health.{key} = {value!r}: expected a number")
        values[key] = float(value)
    for key in ("capacity_ah", "capacity_var_ah2", "r0_factor", "r0_factor_var"):
        if not (math.isfinite(values[key]) and values[key] > 0.0):
            raise StateFileError(path, f"health.{key} = {values[key]!r}: expected a number > 0")
    serial = raw.get("serial_number", "")
    if not isinstance(serial, str):
        raise StateFileError(path, f"health.serial_number = {serial!r}: expected a string")
    return HealthState(serial_number=serial, **values)


def _cells(path: Path, raw: Any) -> CellsState:
    """The ``cells`` mapping of a state file, validated: ``x`` N rows of 3 finite numbers and
    ``p`` N 3 x 3 blocks of finite numbers with a non-negative diagonal, N >= 2."""
    if not isinstance(raw, dict):
        raise StateFileError(path, "cells: expected a mapping")
    try:
        x = np.asarray(raw.get("x"), dtype=float)
        p = np.asarray(raw.get("p"), dtype=float)
    except (TypeError, ValueError) as exc:
        raise StateFileError(path, f"cells: expected numbers ({exc})") from exc
    n = x.shape[0] if x.ndim == 2 else 0
    if n < 2 or x.shape != (n, 3) or p.shape != (n, 3, 3):
        raise StateFileError(
            path, f"cells: x {x.shape} and p {p.shape}: expected (N, 3) and (N, 3, 3), N >= 2"
        )
    if not (np.isfinite(x).all() and np.isfinite(p).all()):
        raise StateFileError(path, "cells: expected finite numbers")
    if (np.diagonal(p, axis1=1, axis2=2) < 0.0).any():
        raise StateFileError(path, "cells.p: a negative variance")
    return CellsState.of_arrays(x, p)


def _hysteresis(path: Path, raw: Any) -> HysteresisState:
    if not isinstance(raw, dict):
        raise StateFileError(path, "hysteresis: expected a mapping")
    branch, var = _number(path, raw, "branch"), _number(path, raw, "var")
    if not (0.0 <= branch <= 1.0 and 0.0 <= var <= HysteresisState.UNKNOWN_VAR):
        raise StateFileError(
            path,
            f"hysteresis: branch {branch!r}, var {var!r}: expected a branch in [0, 1] and a "
            f"variance in [0, {HysteresisState.UNKNOWN_VAR:.4f}]",
        )
    return HysteresisState(branch, var)


def _text(path: Path, raw: dict[str, Any], key: str) -> str:
    value = raw.get(key)
    if not isinstance(value, str) or not value:
        raise StateFileError(path, f"{key} = {value!r}: expected a non-empty string")
    return value


def load_state(path: Path | str) -> SavedState:
    """Read and validate a state file; :class:`StateFileError` for anything wrong with it."""
    p = Path(path).expanduser()
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise StateFileError(p, "no such file") from exc
    except OSError as exc:
        raise StateFileError(p, f"cannot be read ({exc})") from exc
    except UnicodeDecodeError as exc:
        raise StateFileError(p, f"not a text file ({exc.reason} at byte {exc.start})") from exc
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise StateFileError(p, f"not valid YAML ({str(exc).splitlines()[0]})") from exc
    if not isinstance(raw, dict):
        raise StateFileError(p, "expected a YAML mapping")
    if raw.get("format") != FORMAT_VERSION:
        raise StateFileError(p, f"format = {raw.get('format')!r}: expected {FORMAT_VERSION}")
    soc = _number(p, raw, "soc")
    if not 0.0 <= soc <= 1.0:
        raise StateFileError(p, f"soc = {soc!r}: expected a fraction in [0, 1]")
    soc_var = _number(p, raw, "soc_var")
    if not 0.0 < soc_var <= MAX_SOC_VAR:
        raise StateFileError(
            p, f"soc_var = {soc_var!r}: expected a variance in (0, {MAX_SOC_VAR:g}]"
        )
    return SavedState(
        soc=soc,
        soc_var=soc_var,
        stamp_s=_number(p, raw, "stamp_s"),
        estimator=_text(p, raw, "estimator"),
        battery=_text(p, raw, "battery"),
        health=_health(p, raw["health"]) if "health" in raw else None,
        cells=_cells(p, raw["cells"]) if "cells" in raw else None,
        hysteresis=_hysteresis(p, raw["hysteresis"]) if "hysteresis" in raw else None,
    )


@dataclass(frozen=True)
class ResumeDecision:
    """Whether to resume from a saved state; ``reason`` says why (for the log) either way."""

    state: SavedState | None
    reason: str

    @property
    def resume(self) -> bool:
        """True when ``state`` may be used."""
        return self.state is not None


def resume_decision(
    path: Path | str,
    now_s: float,
    resume_max_age_s: float,
    battery: str,
    *,
    future_tolerance_s: float = 1.0,
) -> ResumeDecision:
    """Decide whether the state in ``path`` may be resumed from at time ``now_s`` (s).

    The age is ``now_s - state.stamp_s``; the state is used only if ``0 <= age <=
    resume_max_age_s`` (a state up to ``future_tolerance_s`` "in the future" counts as age 0:
    stamps of one source may jitter), and only for the same ``battery``.
    """
    try:
        state = load_state(path)
    except StateFileError as exc:
        moved = set_aside(path)
        note = f"; set aside as {moved}" if moved is not None else ""
        return ResumeDecision(None, f"no usable saved state: {exc}{note}")
    if state.battery != battery:
        return ResumeDecision(
            None, f"saved state in {path} is for battery {state.battery!r}, not {battery!r}"
        )
    age_s = now_s - state.stamp_s
    if age_s < -future_tolerance_s:
        return ResumeDecision(
            None,
            f"saved state in {path} is {-age_s:.1f} s in the future of the first sample "
            "(clock changed?)",
        )
    if age_s > resume_max_age_s:
        return ResumeDecision(
            None,
            f"saved state in {path} is {age_s:.1f} s old, older than resume_max_age_s = "
            f"{resume_max_age_s:g} s",
        )
    return ResumeDecision(
        state,
        f"resuming from {path}: SoC {state.soc:.4f} (std {math.sqrt(state.soc_var):.4f}) saved "
        f"{max(age_s, 0.0):.1f} s before the first sample by {state.estimator}",
    )


#: A saved health outside these is not this pack's (a corrupted or edited file): its capacity
#: over the battery file's (a pack at a fifth of its capacity is long dead; twice it, another
#: pack), its ``R_0`` factor (the bundled aged LFP pack learns 10.7: its film's growth all
#: lands on the file's small ``R_0``, docs/architecture.md#health).
HEALTH_PLAUSIBLE = {"soh": (0.2, 2.0), "r0_factor": (0.01, 100.0)}


def resume_health(
    path: Path | str, battery: str, file_capacity_ah: float
) -> tuple[HealthState | None, str]:
    """The health saved in ``path`` for ``battery`` (whose file's capacity is
    ``file_capacity_ah``), whatever the file's age, and why (for the log): None when the file is
    absent or unusable (left in place: :func:`resume_decision` sets it aside), holds no health,
    belongs to another battery, or is implausible for it (:data:`HEALTH_PLAUSIBLE`)."""
    try:
        state = load_state(path)
    except StateFileError as exc:
        return None, f"no saved health: {exc}"
    if state.battery != battery:
        return None, f"saved health in {path} is for battery {state.battery!r}, not {battery!r}"
    if state.health is None:
        return None, f"no saved health in {path}"
    h = state.health
    soh = h.capacity_ah / file_capacity_ah
    (soh_lo, soh_hi), (r0_lo, r0_hi) = HEALTH_PLAUSIBLE["soh"], HEALTH_PLAUSIBLE["r0_factor"]
    if not (soh_lo <= soh <= soh_hi and r0_lo <= h.r0_factor <= r0_hi):
        return None, (
            f"saved health in {path} is not this pack's: capacity {h.capacity_ah:g} Ah "
            f"({soh:.3g} of the file's {file_capacity_ah:g} Ah; {soh_lo:g}-{soh_hi:g} "
            f"plausible), R0 factor {h.r0_factor:g} ({r0_lo:g}-{r0_hi:g}): starting from the "
            "file's values"
        )
    return h, (
        f"health from {path}: capacity {h.capacity_ah:.3f} Ah "
        f"(std {math.sqrt(h.capacity_var_ah2):.3f}), R0 factor {h.r0_factor:.3f} "
        f"(std {math.sqrt(h.r0_factor_var):.3f})"
        + (f", pack {h.serial_number!r}" if h.serial_number else "")
    )
