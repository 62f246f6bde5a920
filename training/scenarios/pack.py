"""Packs of Ns × Np cells of one LMN model with cell-to-cell spread, stepped at once with
numpy (lmncell.runtime.vector.VectorCells).

The Np cells of a parallel group share the group's current by their impedance: each step the
cells' voltages are linearised around an equal share (two trial steps) and the currents chosen
so that all cells of a group reach the same voltage to first order, summing exactly to the
string current. The Ns groups in series carry the string current.

A cell's linearised resistance is taken as at least MIN_RESISTANCE_SHARE of the pack's median
at its start. In drive cycles it stays far above that: at least 0.60 of it over WLTC, US06
and UDDS (three times each, 100s40p) at 0, 25 and 40 °C ambient, with a model of the Panasonic
25 °C drive cycles and one of the A123 records. Below it the model
has left what it knows and is no longer passive: the current partition of a model driven far
beyond its temperatures gave −3 mΩ, and an equal-voltage share then sent kiloamperes round the
group. Such a step counts as out of range.

Spread: per cell, the capacity and the overpotential scale r (resistances and polarisation)
are drawn from normal distributions with the given relative standard deviations, seeded,
clipped to ±3σ.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from lmncell.data.records import DataError
from lmncell.runtime.model import LmnModel
from lmncell.runtime.vector import VectorCells
from lmncell.scenarios.drive import empty_reason, full_reason

DELTA_A = 1e-3     # current step of the linearisation (A)
MIN_RESISTANCE_SHARE = 0.1   # a cell's linearised resistance at least this share of the start's
MIN_RESISTANCE_OHM = 1e-6    # … and at least this (a model not passive even at its start)


@dataclass(frozen=True)
class PackSpec:
    """Ns × Np cells, relative spreads (standard deviations) of capacity and resistance."""

    n_series: int
    n_parallel: int
    capacity_spread: float = 0.0
    resistance_spread: float = 0.0
    seed: int = 0
    vehicle_cells: int | None = None   # a sample string of a larger vehicle pack: its size

    @property
    def power_share(self) -> float:
        """The share of the vehicle's pack power these cells carry: 1 for the whole pack,
        cells/vehicle_cells for a sample string of it."""
        cells = self.n_series * self.n_parallel
        return cells / self.vehicle_cells if self.vehicle_cells else 1.0

    @property
    def label(self) -> str:
        return f"{self.n_series}s{self.n_parallel}p"


def parse_pack(text: str) -> tuple[int, int]:
    """'96s3p' → (96, 3)."""
    m = re.fullmatch(r"\s*(\d+)\s*s\s*(\d+)\s*p\s*", text or "", flags=re.IGNORECASE)
    if not m or int(m[1]) < 1 or int(m[2]) < 1:
        raise DataError(f"--pack {text!r}: expected NsNp such as 96s3p (Ns, Np ≥ 1)")
    return int(m[1]), int(m[2])


def parse_spread(text: str) -> dict[str, float]:
    """'capacity=0.02,resistance=0.05' → relative standard deviations."""
    out: dict[str, float] = {}
    for part in (text or "").split(","):
        key, _, value = part.partition("=")
        key = key.strip()
        if key not in ("capacity", "resistance"):
            raise DataError(f"--spread {text!r}: expected capacity=F,resistance=F (relative "
                            f"standard deviations), not {part!r}")
        try:
            v = float(value)
        except ValueError:
            raise DataError(f"--spread {key}={value!r}: expected a number") from None
        if not 0.0 <= v < 0.3:
            raise DataError(f"--spread {key}={v!r}: expected a relative spread within 0…0.3")
        if key in out:
            raise DataError(f"--spread {text!r}: names {key} twice; expected each once")
        out[key] = v
    return out


def cell_parameters(model: LmnModel, spec: PackSpec) -> tuple[np.ndarray, np.ndarray]:
    """Per cell (series-major: group g holds cells g·Np … g·Np + Np − 1) the capacity (Ah)
    and the overpotential scale, drawn reproducibly from spec.seed."""
    n = spec.n_series * spec.n_parallel
    rng = np.random.default_rng(spec.seed)
    dc = np.clip(rng.standard_normal(n), -3, 3) * spec.capacity_spread
    dr = np.clip(rng.standard_normal(n), -3, 3) * spec.resistance_spread
    return model.capacity_ah * (1.0 + dc), 1.0 + dr


class Pack:
    """A pack stepped by its string current or its power."""

    def __init__(self, model: LmnModel, spec: PackSpec, soc0: float, ambient_c: float,
                 temperature_is_cell: bool = False,
                 cell_temperature_start_c: float | None = None) -> None:
        """cell_temperature_start_c: every cell's temperature at the start (°C), with the
        thermal model driven by ambient_c; None: rested at ambient_c (VectorCells)."""
        cap, r = cell_parameters(model, spec)
        self.spec, self.ambient_c = spec, float(ambient_c)
        self.cells = VectorCells(model, np.full(cap.size, soc0), capacity_ah=cap,
                                 resistance_scale=r, temperature_c=ambient_c,
                                 temperature_is_cell=temperature_is_cell,
                                 cell_temperature_start_c=cell_temperature_start_c)
        self.current_a = np.zeros(cap.size)
        self.resistance_floor_ohm = max(MIN_RESISTANCE_SHARE * float(np.median(
            self._resistances(self.current_a))), MIN_RESISTANCE_OHM)
        self.floored = False     # the last share raised a resistance to resistance_floor_ohm

    @property
    def voltage_v(self) -> float:
        """Pack voltage: the sum over the series groups of each group's (mean) voltage."""
        g = self.cells.voltage_v.reshape(self.spec.n_series, self.spec.n_parallel)
        return float(g.mean(axis=1).sum())

    def share(self, string_current_a: float) -> np.ndarray:
        """Cell currents for a string current (A, > 0 charges): equal voltages within each
        parallel group to first order, each group's currents summing to the string current."""
        ns, npar = self.spec.n_series, self.spec.n_parallel
        i0 = np.full(self.cells.n, string_current_a / npar)
        self.floored = False
        if npar == 1:
            return i0
        u0 = self.cells.peek(i0, self.ambient_c)
        b = self._resistances(i0, u0)
        self.floored = bool((b < self.resistance_floor_ohm).any())
        b = np.maximum(b, self.resistance_floor_ohm).reshape(ns, npar)   # Ω, > 0
        a = u0.reshape(ns, npar) - b * i0.reshape(ns, npar)
        v = (string_current_a + np.sum(a / b, axis=1)) / np.sum(1.0 / b, axis=1)
        i = (v[:, None] - a) / b
        i += (string_current_a - i.sum(axis=1))[:, None] / npar     # exact sum despite round-off
        return i.ravel()

    def _resistances(self, current_a: np.ndarray, u0: np.ndarray | None = None) -> np.ndarray:
        """Each cell's linearised resistance dU/dI (Ω) of a step with these currents (A); u0:
        their voltages where already known."""
        if u0 is None:
            u0 = self.cells.peek(current_a, self.ambient_c)
        return (self.cells.peek(current_a + DELTA_A, self.ambient_c) - u0) / DELTA_A

    def step_current(self, string_current_a: float) -> np.ndarray:
        self.current_a = self.share(string_current_a)
        return self.cells.step(self.current_a, self.ambient_c)

    def step_power(self, pack_power_w: float) -> np.ndarray:
        """One step drawing pack_power_w (W, > 0 discharges) at the last pack voltage."""
        return self.step_current(-pack_power_w / self.voltage_v)


def drive_pack(model: LmnModel, spec: PackSpec, pack_power_w: np.ndarray, ambient_c: float,
               soc0: float, cutoff_v: float = 0.0,
               cell_temperature_start_c: float | None = None) -> dict:
    """Drive a pack through a power profile (one value per model step); the figures a sweep
    reports: the weakest cell's minimum voltage and SoC, the hottest cell, the string's Ah,
    and the steps in which a cell left the trained region (VectorCells.out_of_range) or the
    share floored a resistance (out_of_range_steps).
    The run stops after the first step that leaves a cell empty (drive.empty_reason: its
    voltage below cutoff_v (V) or its SoC below 0) or full (drive.full_reason: its SoC above
    1, as a single cell's run stops): "stop" says why, "stopped_at_s" when.
    cell_temperature_start_c: the cells' temperature at the start (°C; None: rested at the
    ambient)."""
    pack = Pack(model, spec, soc0, ambient_c,
                cell_temperature_start_c=cell_temperature_start_c)
    ts = model.sample_time_s
    v_min, v_max, t_max = np.inf, -np.inf, -np.inf
    string_ah = energy_wh = 0.0
    stop, steps, outside = "", 0, 0
    for p in np.asarray(pack_power_w, dtype=float).tolist():
        u = pack.step_power(p)
        steps += 1
        outside += bool(pack.cells.out_of_range.any() or pack.floored)
        v_min, v_max = min(v_min, float(u.min())), max(v_max, float(u.max()))
        t_max = max(t_max, float(pack.cells.cell_temperature_c.max()))
        i_string = float(pack.current_a[: spec.n_parallel].sum())
        string_ah += abs(i_string) * ts / 3600.0
        energy_wh += -i_string * pack.voltage_v * ts / 3600.0
        stop = (empty_reason(float(u.min()), float(pack.cells.soc.min()), cutoff_v)
                or full_reason(float(u.max()), float(pack.cells.soc.max())))
        if stop:
            break
    soc = pack.cells.soc
    return {"pack": spec.label, "voltage_min_v": v_min, "voltage_max_v": v_max,
            "soc_end": float(soc.mean()), "soc_end_min": float(soc.min()),
            "ah_throughput": string_ah, "pack_energy_kwh": energy_wh / 1000.0,
            "cell_temperature_max_c": t_max if model.thermal is not None else float("nan"),
            "cell_steps": int(steps * pack.cells.n), "steps": steps, "stop": stop,
            "out_of_range_steps": outside,
            "stopped_at_s": steps * ts if stop else None}
