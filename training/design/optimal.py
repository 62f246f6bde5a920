"""Experiment design: locally D-optimal current sequences chained into a target SoC profile.

Each sequence is a piecewise-constant current (one level per hold time) that maximises
log det of the Fisher information of a simple linear cell model's parameters (R0, and R and τ of
each RC branch, relative sensitivities) subject to: |i| ≤ I_max (C-rate and cycler limit), the
charge it moves equal to its share of the SoC profile (an equality on Σ i·t_hold), and the
voltage the design model predicts within the cell's limits. Solved with scipy's SLSQP from a
deterministic start; sequences are designed one after the other, each from the state the previous
one leaves (SoC and RC voltages). Current > 0 charges; SI units.

Design model: u = OCV(SoC) + c + R0·i + Σ_m v_m, v_m(k) = e_m·v_m(k−1) + R_m·(1−e_m)·i(k), with
c the local OCV offset (0 nominal).

Hold time: each level is held for the settling time of the design model's slowest RC element
(SETTLING_TAUS × τ, a multiple of the cycler's minimum hold, at most a tenth of a sequence so
that a sequence still visits ten current levels), so that every level shows the cell's
resistance with its polarisation settled, not only its fast response. The random programmes of
the comparison use the same hold. On the PyBaMM cell (τ 11.6 s → 30 s holds) this decided the
comparison: with the cycler's 10 s the design lost the EV discharge to the APRBS median (2.02
vs 2.00 mV), with 30 s for all programmes it wins all three profiles (1.67/2.04/1.86 vs
2.12/2.40/2.17 mV; also against APRBS seeds 6…15).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from lmncell.config import TrainConfig
from lmncell.data.records import DataError, Record, RecordMeta
from lmncell.design import DESIGN_METHODS, INFORMATION_KINDS
from lmncell.report.jsontext import json_text
from lmncell.runtime.model import replaced_whole, write_text_whole
from scipy.optimize import minimize
from scipy.signal import lfilter

# A123 26650 LFP, mean of the C/30 charge and discharge OCV at 25 °C (shipped data), 0…100 % SoC
DEFAULT_OCV_SOC = tuple(np.linspace(0.0, 1.0, 11))
DEFAULT_OCV_V = (2.1606, 3.1778, 3.2444, 3.2795, 3.3013, 3.308, 3.317, 3.3303, 3.3452, 3.3519,
                 3.59)


@dataclass
class CellSpec:
    """The cell as the design sees it (Ah, V, Ω, s)."""

    capacity_ah: float
    voltage_min_v: float = 2.0
    voltage_max_v: float = 3.6
    max_c_rate: float = 20.0
    r0_ohm: float = 0.010
    rc: list[tuple[float, float]] = field(default_factory=lambda: [(0.008, 10.0),
                                                                   (0.012, 150.0)])
    ocv_soc: tuple[float, ...] = DEFAULT_OCV_SOC
    ocv_v: tuple[float, ...] = DEFAULT_OCV_V
    # every resistance × this factor over SoC (linear between points, held beyond; none: 1)
    r_scale_soc: tuple[float, ...] = ()
    r_scale: tuple[float, ...] = ()

    def ocv(self, soc: np.ndarray) -> np.ndarray:
        return np.interp(soc, self.ocv_soc, self.ocv_v)

    def resistance_scale(self, soc: np.ndarray) -> np.ndarray | float:
        return np.interp(soc, self.r_scale_soc, self.r_scale) if self.r_scale else 1.0


def held_soc(soc0: float, current_a: np.ndarray, ts: float, capacity_ah: float) -> np.ndarray:
    """SoC at the end of each sample for a current (A, > 0 charges) held over each sample."""
    return soc0 + np.cumsum(current_a) * ts / (3600.0 * capacity_ah)


@dataclass
class CyclerSpec:
    max_current_a: float = 100.0
    hold_s: float = 10.0
    sample_time_s: float = 1.0


SETTLING_TAUS = 3.0      # a first-order response settles to 95 % in 3 τ
MIN_LEVELS_PER_SEQUENCE = 10


def slowest_time_constant(cell: CellSpec) -> float:
    """The longest time constant (s) of the design model's RC elements (0 without any)."""
    return max((t for _, t in cell.rc), default=0.0)


def settling_hold(cell: CellSpec, cyc: CyclerSpec, spec: DesignSpec) -> float:
    """The hold time (s) of the programme's levels: SETTLING_TAUS × the design model's longest
    time constant, rounded to a multiple of the cycler's minimum hold (at least one), and no
    longer than allows MIN_LEVELS_PER_SEQUENCE levels in a sequence (the built-in cell, whose
    slow RC has 159 s, won two of three profiles with 30 s and one with 50 s holds)."""
    tau = slowest_time_constant(cell)
    longest = max(cyc.hold_s, cyc.hold_s * np.floor(spec.sequence_s / MIN_LEVELS_PER_SEQUENCE
                                                    / cyc.hold_s))
    return float(min(max(cyc.hold_s, cyc.hold_s * round(SETTLING_TAUS * tau / cyc.hold_s)),
                     longest))


def current_limit(cell: CellSpec, cyc: CyclerSpec) -> float:
    """The programme's current bound (A): the cell's C-rate limit or the cycler's, the lower."""
    return min(cell.max_c_rate * cell.capacity_ah, cyc.max_current_a)


@dataclass
class DesignSpec:
    soc_profile: list[float]
    duration_s: float = 7200.0
    sequence_s: float = 300.0
    voltage_margin_v: float = 0.02
    soc_margin: float = 0.015     # SoC stays within the profile's range widened by this
    amplitude_levels: int = 4     # sequences cycle through bands I_max, I_max/2, I_max/4, …
    method: str = "spacefill"     # "spacefill" (default) or "slsqp", see design_sequence
    information: str = "lmn"      # "lmn" (default) or "rc", see sensitivities


def voltage_window(cell: CellSpec, spec: DesignSpec) -> tuple[float, float]:
    """The voltages (V) a programme's predicted voltage must stay within: the cell's limits
    narrowed by the design's margin."""
    return cell.voltage_min_v + spec.voltage_margin_v, cell.voltage_max_v - spec.voltage_margin_v


def soc_window(spec: DesignSpec) -> tuple[float, float]:
    """The SoC a designed sequence stays within: the profile's range widened by the margin."""
    return min(spec.soc_profile) - spec.soc_margin, max(spec.soc_profile) + spec.soc_margin


def amplitude_band(spec: DesignSpec, i_max: float, index: int, mean: float) -> float:
    """Current bound of sequence `index`: the local operating range it is designed for (the
    network's local models live at different current amplitudes), never below what its charge
    needs."""
    band = i_max * 0.5 ** (index % max(spec.amplitude_levels, 1))
    return min(i_max, max(band, 1.25 * abs(mean)))


def parse_profile(text: str) -> list[float]:
    """'0.8,0.2,0.8' or the shorthand '0.8:0.2' into SoC points (fractions)."""
    try:
        pts = [float(x) for x in text.replace(":", ",").split(",") if x.strip()]
    except ValueError as exc:
        raise DataError(f"--soc-profile {text!r}: expected SoC fractions like 0.8,0.2,0.8") from exc
    if len(pts) < 2 or any(not 0.0 <= p <= 1.0 for p in pts):
        raise DataError(f"--soc-profile {text!r}: expected at least two SoC points within 0…1")
    return pts


# ----- the design model -------------------------------------------------------------------------
def predict(cell: CellSpec, current: np.ndarray, ts: float, soc0: float,
            v0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Voltage (V), SoC and final RC voltages for a current held over each sample (the
    resistances scaled by the cell's resistance_scale at each sample's SoC)."""
    soc = held_soc(soc0, current, ts, cell.capacity_ah)
    scaled = current * cell.resistance_scale(soc)
    u = cell.ocv(soc) + cell.r0_ohm * scaled
    vend = np.empty(len(cell.rc))
    for m, (r, tau) in enumerate(cell.rc):
        e = np.exp(-ts / tau)
        v, _ = lfilter([r * (1 - e)], [1.0, -e], scaled, zi=[e * v0[m]])
        u = u + v
        vend[m] = v[-1]
    return u, soc, vend


# six amplitude knots: with three, the sequences sat at two or three current levels (PRBS-like,
# poor for a network whose local models live at different currents); six spread the levels
# (APRBS-like), which lowered the trained LMN's error on the virtual cell's drive cycles
AMPLITUDE_KNOTS = tuple(k / 6 for k in range(1, 7))
AMPLITUDE_KNOT_SPACING = 1 / 6


OFFSET_SCALE_V = 0.01   # the local OCV offset's scale in the relative sensitivities


# the default LMN's filter ladder: its local models' dynamic regressors are low-passes of the
# current at these time constants (s), the slow end of each pair (5, 30, 150, 800, 3000 s)
LMN_FILTER_TAUS_S = tuple(slow for _, slow in TrainConfig().filter_pairs())


def sensitivities(cell: CellSpec, current: np.ndarray, ts: float,
                  i_ref: float | None = None, information: str = "lmn") -> np.ndarray:
    """(N, p) sensitivity columns of the model the programme identifies.

    Both kinds: R0 (the current), a_1…a_K (the resistance a piecewise-linear function of
    |i|/i_ref over AMPLITUDE_KNOTS, all 0 in the nominal model: they ask for several amplitude
    levels, as the network's local models at different currents need) and c, the local OCV
    offset (scaled by OFFSET_SCALE_V: it asks to separate the offset from the drop under the
    mean current). "lmn" (the paper's model-based design): the local model's dynamic regressors,
    low-passes of the current at LMN_FILTER_TAUS_S, slow relaxation included. "rc": relative
    sensitivities θ·∂u/∂θ of R and τ of each RC element of the cell's design model. Log det is
    invariant to each column's scale, so only the time constants matter. i_ref: the sequence's
    current bound."""
    i_ref = max(float(np.abs(current).max()), 1e-9) if i_ref is None else i_ref
    x = np.abs(current) / i_ref
    cols = [cell.r0_ohm * current]
    for knot in AMPLITUDE_KNOTS:   # piecewise-linear resistance over |i|: hat functions
        hat = np.clip(1.0 - np.abs(x - knot) / AMPLITUDE_KNOT_SPACING, 0.0, None)
        cols.append(cell.r0_ohm * hat * current)
    if information == "lmn":
        for tau in LMN_FILTER_TAUS_S:
            e = np.exp(-ts / tau)
            cols.append(cell.r0_ohm * lfilter([1 - e], [1.0, -e], current))
    elif information == "rc":
        for r, tau in cell.rc:
            e = np.exp(-ts / tau)
            v = lfilter([r * (1 - e)], [1.0, -e], current)
            tau2 = tau * 1.01
            e2 = np.exp(-ts / tau2)
            v2 = lfilter([r * (1 - e2)], [1.0, -e2], current)
            cols += [v, (v2 - v) / 0.01]
    else:
        raise DataError(f"design information {information!r}: expected one of "
                        f"{', '.join(INFORMATION_KINDS)}")
    cols.append(np.full(current.size, OFFSET_SCALE_V))
    return np.column_stack(cols)


def log_det_information(cell: CellSpec, current: np.ndarray, ts: float,
                        i_ref: float | None = None, information: str = "lmn") -> float:
    S = sensitivities(cell, current, ts, i_ref, information)
    sign, ld = np.linalg.slogdet(S.T @ S + 1e-12 * np.eye(S.shape[1]))
    return float(ld) if sign > 0 else -np.inf


# ----- one sequence ---------------------------------------------------------------------------
@dataclass
class Sequence:
    current_a: np.ndarray
    voltage_v: np.ndarray
    soc: np.ndarray
    log_det: float
    success: bool


def _expand(levels: np.ndarray, per: int) -> np.ndarray:
    return np.repeat(levels, per)


SWAP_PASSES = 6
GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def design_sequence(cell: CellSpec, cyc: CyclerSpec, spec: DesignSpec, soc0: float,
                    v0: np.ndarray, dsoc: float, i_max: float, index: int) -> Sequence:
    """The sequence that moves SoC by dsoc from (soc0, v0), by spec.method:

    "spacefill": its levels are evenly spaced over the band around the charge-moving mean (a
    space-filling set of current amplitudes: every current the network's local models live at
    is visited, none twice) and their order is chosen for the largest log det of the information
    (deterministic pairwise-swap search from a golden-ratio order; each sequence on its own: a
    sequential design, with the earlier sequences' information added, did worse on the PyBaMM
    cell), under the voltage and SoC limits (the spread shrinks, as for the random programmes,
    only where the start breaks them).
    "slsqp": the levels themselves maximise log det (SLSQP); they go to the band's edges, which
    gives a D-optimal linear model but leaves the currents in between unvisited (on the PyBaMM
    cell its LMNs lost to APRBS, whose levels are spread)."""
    if spec.method == "spacefill":
        return _spacefill_sequence(cell, cyc, spec, soc0, v0, dsoc, i_max, index)
    if spec.method != "slsqp":
        raise DataError(f"design method {spec.method!r}: expected one of "
                        f"{', '.join(DESIGN_METHODS)}")
    ts, per = cyc.sample_time_s, round(cyc.hold_s / cyc.sample_time_s)
    n_levels, mean = _sequence_mean(cell, cyc, spec, dsoc, i_max, index)
    target_as = dsoc * cell.capacity_ah * 3600.0          # charge to move (A·s)
    # deterministic start: alternating steps of growing amplitude around the mean (PRBS-like)
    k = np.arange(n_levels)
    amp = 0.5 * (i_max - abs(mean))
    x0 = mean + amp * np.sign(np.sin(2 * np.pi * k / max(n_levels / 3.0, 2.0) + 0.3)) * \
        (0.5 + 0.5 * (k % 3) / 2)
    x0 = x0 - (x0.sum() * cyc.hold_s - target_as) / (n_levels * cyc.hold_s)
    lo_v, hi_v = voltage_window(cell, spec)
    soc_lo, soc_hi = soc_window(spec)

    def volt(levels: np.ndarray) -> np.ndarray:
        return predict(cell, _expand(levels, per), ts, soc0, v0)[0]

    step_soc = cyc.hold_s / (3600.0 * cell.capacity_ah)

    def soc_path(levels: np.ndarray) -> np.ndarray:
        return soc0 + np.cumsum(levels) * step_soc

    cons = [{"type": "eq", "fun": lambda x: (x.sum() * cyc.hold_s - target_as) / 3600.0},
            {"type": "ineq", "fun": lambda x: np.concatenate([volt(x) - lo_v, hi_v - volt(x)])},
            {"type": "ineq", "fun": lambda x: 10 * np.concatenate([soc_path(x) - soc_lo,
                                                                   soc_hi - soc_path(x)])}]
    res = minimize(lambda x: -log_det_information(cell, _expand(x, per), ts, i_max,
                                         spec.information) / 10.0,
                   np.clip(x0, -i_max, i_max), method="SLSQP",
                   bounds=[(-i_max, i_max)] * n_levels, constraints=cons,
                   options={"maxiter": 200, "ftol": 1e-7})
    levels = exact_charge(np.clip(res.x, -i_max, i_max), target_as / cyc.hold_s, i_max)
    cur = _expand(levels, per)
    u, soc, _ = predict(cell, cur, ts, soc0, v0)
    return Sequence(cur, u, soc, log_det_information(cell, cur, ts, i_max, spec.information),
                    bool(res.success))


def _sequence_mean(cell: CellSpec, cyc: CyclerSpec, spec: DesignSpec, dsoc: float,
                   i_max: float, index: int) -> tuple[int, float]:
    n_levels = round(spec.sequence_s / cyc.hold_s)
    mean = dsoc * cell.capacity_ah * 3600.0 / (n_levels * cyc.hold_s)
    if abs(mean) > i_max:
        raise DataError(f"sequence {index}: moving SoC by {dsoc:+.3f} in {spec.sequence_s:.0f} s "
                        f"needs {abs(mean):.2f} A on average, above the {i_max:.2f} A limit; "
                        "give a longer --duration or a smaller SoC swing")
    return n_levels, mean


def _spacefill_sequence(cell: CellSpec, cyc: CyclerSpec, spec: DesignSpec, soc0: float,
                        v0: np.ndarray, dsoc: float, i_max: float, index: int) -> Sequence:
    ts, per = cyc.sample_time_s, round(cyc.hold_s / cyc.sample_time_s)
    n_levels, mean = _sequence_mean(cell, cyc, spec, dsoc, i_max, index)
    grid = np.linspace(-1.0, 1.0, n_levels)                      # zero mean: exact charge
    # deterministic, irregular start: the golden-ratio (low-discrepancy) order of the levels
    start = np.argsort(np.mod(np.arange(1, n_levels + 1) * GOLDEN, 1.0))
    lo_v, hi_v = voltage_window(cell, spec)
    soc_lo, soc_hi = soc_window(spec)

    def levels(order: np.ndarray, spread: float) -> np.ndarray:
        return mean + spread * (i_max - abs(mean)) * grid[order]

    def feasible(x: np.ndarray) -> bool:
        u, soc, _ = predict(cell, _expand(x, per), ts, soc0, v0)
        return bool(u.min() >= lo_v and u.max() <= hi_v and soc.min() >= soc_lo
                    and soc.max() <= soc_hi)

    spread = _largest_spread(lambda f: feasible(levels(start, f)))
    order = start.copy()
    best = log_det_information(cell, _expand(levels(order, spread), per), ts, i_max,
                               spec.information)
    for _ in range(SWAP_PASSES):
        improved = False
        for a in range(n_levels - 1):
            for b in range(a + 1, n_levels):
                order[[a, b]] = order[[b, a]]
                x = levels(order, spread)
                ld = log_det_information(cell, _expand(x, per), ts, i_max,
                                         spec.information)
                if ld > best + 1e-9 and feasible(x):
                    best, improved = ld, True
                else:
                    order[[a, b]] = order[[b, a]]
        if not improved:
            break
    cur = _expand(levels(order, spread), per)
    u, soc, _ = predict(cell, cur, ts, soc0, v0)
    return Sequence(cur, u, soc, best, True)


SPREAD_GRID = np.linspace(1.0, 0.0, 21)[:-1]   # the spreads tried first, 1 … 0.05
SPREAD_HALVINGS = 10        # below the grid's least, halved this many times (to 5e-5)


def _largest_spread(feasible: Callable[[float], bool]) -> float:
    """The largest spread (share of the band around the mean current) of SPREAD_GRID that
    feasible(spread) accepts; below its least, that share halved until one is accepted (long
    holds, whose levels move the SoC out of its window at any coarser spread: without it such a
    sequence held its mean current alone); 0 where none is."""
    for spread in (*SPREAD_GRID, *(SPREAD_GRID[-1] * 0.5 ** np.arange(1, SPREAD_HALVINGS + 1))):
        if feasible(float(spread)):
            return float(spread)
    return 0.0


def holds_one_current(current_a: np.ndarray) -> bool:
    """Whether a sequence's current is one level throughout (no excitation)."""
    return bool(np.ptp(current_a) <= 1e-9 * max(1.0, float(np.max(np.abs(current_a)))))


def exact_charge(levels: np.ndarray, target_sum: float, i_max: float) -> np.ndarray:
    """Shift the levels (only those with headroom) so that they sum exactly to target_sum,
    never beyond ±i_max."""
    x = levels.copy()
    for _ in range(50):
        gap = target_sum - x.sum()
        if abs(gap) <= 1e-12 * max(1.0, abs(target_sum)):
            break
        free = (x < i_max) if gap > 0 else (x > -i_max)
        if not free.any():
            break
        x[free] = np.clip(x[free] + gap / free.sum(), -i_max, i_max)
    return x


# ----- the programme --------------------------------------------------------------------------
@dataclass
class Programme:
    time_s: np.ndarray
    current_a: np.ndarray
    voltage_v: np.ndarray
    soc: np.ndarray
    sequence_starts: list[int]
    profile_points: list[tuple[float, float]]
    log_dets: list[float]
    settings: dict

    def to_record(self, source: str) -> Record:
        return Record(self.time_s, self.current_a, self.voltage_v,
                      RecordMeta(source, "design", "current > 0 charges",
                                 float(self.time_s[1] - self.time_s[0])), soc_ref=self.soc)


def allocate(profile: list[float], n_seq: int) -> tuple[list[float], list[int]]:
    """SoC change of every sequence, and sequences per profile leg (in proportion to |ΔSoC|)."""
    legs = np.diff(profile)
    if np.all(np.abs(legs) < 1e-12):
        return [0.0] * n_seq, [n_seq] + [0] * (legs.size - 1)
    share = np.abs(legs) / np.abs(legs).sum() * n_seq
    counts = np.maximum(1, np.floor(share).astype(int))
    while counts.sum() < n_seq:
        counts[np.argmax(share - counts)] += 1
    while counts.sum() > n_seq:
        counts[np.argmax(counts)] -= 1
    steps = [float(d) / c for d, c in zip(legs, counts, strict=True) for _ in range(c)]
    return steps, counts.tolist()


def sequence_count(spec: DesignSpec) -> int:
    """The number of sequences: the duration over the sequence length, rounded; at least one
    per leg of the SoC profile, else a DataError (a duration shorter than one sequence was
    taken as one sequence, longer than asked)."""
    n_seq = round(spec.duration_s / spec.sequence_s)
    if n_seq < len(spec.soc_profile) - 1:
        raise DataError(f"--duration {spec.duration_s:g} s gives {n_seq} sequence(s) of "
                        f"{spec.sequence_s:g} s, fewer than the {len(spec.soc_profile) - 1} "
                        "leg(s) of the SoC profile; expected a duration of at least "
                        f"{(len(spec.soc_profile) - 1) * spec.sequence_s:g} s (or a shorter "
                        "--sequence)")
    return n_seq


def check_design(cell: CellSpec, cyc: CyclerSpec, spec: DesignSpec) -> None:
    """DataError for limits that no programme can meet: a voltage window that is empty, or a
    sequence too short for two levels of the cycler's hold time (one level is no
    excitation)."""
    if not cell.voltage_min_v + 2 * spec.voltage_margin_v < cell.voltage_max_v:
        raise DataError(f"--voltage-min {cell.voltage_min_v:g} V and --voltage-max "
                        f"{cell.voltage_max_v:g} V leave no voltage window (the design keeps "
                        f"{spec.voltage_margin_v:g} V inside each); expected the minimum well "
                        "below the maximum")
    if spec.sequence_s < 2 * cyc.hold_s:
        raise DataError(f"--sequence {spec.sequence_s:g} s holds fewer than two levels of the "
                        f"cycler's hold time --hold {cyc.hold_s:g} s; expected a sequence of at "
                        f"least {2 * cyc.hold_s:g} s (or a shorter --hold)")
    check_sampling(cyc, spec)


MAX_PROGRAMME_SAMPLES = 2_000_000   # 23 days at 1 s; as a drive cycle run's steps


def check_sampling(cyc: CyclerSpec, spec: DesignSpec) -> None:
    """DataError where the hold time (--hold) is shorter than one sample (--sample-time), a
    sequence shorter than two, or the programme more than MAX_PROGRAMME_SAMPLES samples (hours
    of design and gigabytes; an IndexError or a MemoryError before)."""
    ts = cyc.sample_time_s
    for option, length, least in (("--hold", cyc.hold_s, 1), ("--sequence", spec.sequence_s, 2)):
        if length < least * ts * (1 - 1e-9):
            raise DataError(f"{option} {length:g} s is shorter than {least} sample(s) of "
                            f"--sample-time {ts:g} s; expected at least {least * ts:g} s (or a "
                            "shorter --sample-time)")
    samples = spec.duration_s / ts
    if samples > MAX_PROGRAMME_SAMPLES:
        raise DataError(f"--duration {spec.duration_s:g} s at --sample-time {ts:g} s is "
                        f"{samples:.3g} samples, more than {MAX_PROGRAMME_SAMPLES}, which would "
                        "take hours and gigabytes; expected a duration of at most "
                        f"{MAX_PROGRAMME_SAMPLES * ts:g} s (or a longer --sample-time)")


def check_voltages(prog_voltage_v: np.ndarray, cell: CellSpec, spec: DesignSpec,
                   largest_mean_a: float) -> None:
    """DataError where the programme's predicted voltage leaves the cell's limits: no current
    moves the SoC through the profile within them (the design fell back to each sequence's
    mean current, which leaves them too); largest_mean_a: the largest |mean current| of a
    sequence (A), which the message names with what lowers it."""
    lo, hi = float(prog_voltage_v.min()), float(prog_voltage_v.max())
    if lo < cell.voltage_min_v or hi > cell.voltage_max_v:
        raise DataError(f"the programme's predicted voltage {lo:.3f} … {hi:.3f} V leaves the "
                        f"limits {cell.voltage_min_v:g} … {cell.voltage_max_v:g} V "
                        "(--voltage-min, --voltage-max): even the mean current that moves the "
                        f"SoC through the profile (up to {largest_mean_a:.3g} A, "
                        f"{largest_mean_a / cell.capacity_ah:.2g} C, in sequences of "
                        f"{spec.sequence_s:g} s) leaves them; expected a longer --duration "
                        f"(now {spec.duration_s:g} s) or a smaller SoC swing, or limits around "
                        "the cell's OCV over the profile's SoC (with --model: the model's)")


def design_programme(cell: CellSpec, cyc: CyclerSpec, spec: DesignSpec,
                     progress=print) -> Programme:
    """Chain locally optimal sequences through the SoC profile (DataError where the limits
    cannot be met: check_design, check_voltages)."""
    check_design(cell, cyc, spec)
    n_seq = sequence_count(spec)
    i_max = current_limit(cell, cyc)
    cyc = dataclasses.replace(cyc, hold_s=settling_hold(cell, cyc, spec))
    progress(f"  hold time {cyc.hold_s:g} s ({SETTLING_TAUS:g} × the design model's longest "
             f"time constant, {slowest_time_constant(cell):.1f} s, at most "
             f"{spec.sequence_s / MIN_LEVELS_PER_SEQUENCE:g} s)")
    steps, counts = allocate(spec.soc_profile, n_seq)
    soc, v = spec.soc_profile[0], np.zeros(len(cell.rc))
    parts, starts, lds, idle, t0 = [], [], [], [], 0
    for k, dsoc in enumerate(steps):
        mean = dsoc * cell.capacity_ah * 3600.0 / spec.sequence_s
        band = amplitude_band(spec, i_max, k, mean)
        seq = design_sequence(cell, cyc, spec, soc, v, dsoc, band, k)
        _, _, v = predict(cell, seq.current_a, cyc.sample_time_s, soc, v)
        soc = float(seq.soc[-1])
        parts.append(seq)
        starts.append(t0)
        t0 += seq.current_a.size
        lds.append(seq.log_det)
        idle.append(holds_one_current(seq.current_a))
        progress(f"  sequence {k + 1}/{n_seq}: ΔSoC {dsoc:+.4f} → SoC {soc:.4f}, log det "
                 f"{seq.log_det:.2f}{'' if seq.success else ' (SLSQP stopped early)'}"
                 + (" (one current throughout: no excitation fits the limits)"
                    if idle[-1] else ""))
    cur = np.concatenate([p.current_a for p in parts])
    n = cur.size
    time_s = cyc.sample_time_s * np.arange(1, n + 1)
    u, socs, _ = predict(cell, cur, cyc.sample_time_s, spec.soc_profile[0],
                         np.zeros(len(cell.rc)))
    ends = np.cumsum(counts) - 1                 # last sequence of each profile leg
    points = [(0.0, spec.soc_profile[0])]
    for leg_end, target in zip(ends, spec.soc_profile[1:], strict=True):
        k_end = starts[leg_end] + parts[leg_end].current_a.size - 1
        points.append((float(time_s[k_end]), float(target)))
    check_voltages(u, cell, spec, float(np.max(np.abs(steps))) * cell.capacity_ah * 3600.0
                   / spec.sequence_s)
    _check_excitation(idle, cyc, spec)
    settings = {"cell": dataclasses.asdict(cell), "cycler": dataclasses.asdict(cyc),
                "design": dataclasses.asdict(spec), "max_current_a": i_max}
    return Programme(time_s, cur, u, socs, starts, points, lds, settings)


def _check_excitation(idle: list[bool], cyc: CyclerSpec, spec: DesignSpec) -> None:
    """DataError where every sequence holds one current (idle: holds_one_current of each): no
    level around its mean keeps the voltage and the SoC inside the limits (the SoC within the
    profile's range ± the margin)."""
    if all(idle):
        raise DataError(f"no sequence has room for excitation: around each one's mean current, "
                        f"levels held {cyc.hold_s:g} s each leave the voltage limits or the SoC "
                        f"range {min(spec.soc_profile):g} … {max(spec.soc_profile):g} "
                        f"(± {spec.soc_margin:g}); expected shorter holds (a shorter --sequence: "
                        "a level is held at most a tenth of it) or wider voltage limits")


SHRINK_STEP = 0.2        # a sequence's spread around its mean shrinks by this share at a time


def shrink_to_fit(prog: Programme, cell: CellSpec, cyc: CyclerSpec, spec: DesignSpec,
                  voltage_of) -> tuple[Programme, dict[int, float]]:
    """The programme with each sequence in which voltage_of (the voltage, V, of another model
    at every programme sample for a current) leaves the design's voltage window shrunk towards
    its mean current, SHRINK_STEP at a time, until it stays inside (its charge, and so the SoC
    profile, unchanged); and {sequence index: the share of its spread kept} for those shrunk.
    A sequence whose mean current alone leaves the window keeps none and is left to the
    caller's check. voltage_of's last call is on the returned programme's current."""
    lo, hi = voltage_window(cell, spec)
    n = prog.current_a.size
    bounds = list(zip(prog.sequence_starts, [*prog.sequence_starts[1:], n], strict=True))
    kept = np.ones(len(bounds))
    cur = prog.current_a.copy()
    while True:
        v = voltage_of(cur)
        out = [k for k, (a, b) in enumerate(bounds)
               if kept[k] > 0 and ((v[a:b] < lo) | (v[a:b] > hi)).any()]
        if not out:
            break
        for k in out:
            a, b = bounds[k]
            kept[k] = max(0.0, round(kept[k] - SHRINK_STEP, 6))
            mean = float(prog.current_a[a:b].mean())
            cur[a:b] = mean + kept[k] * (prog.current_a[a:b] - mean)
    shrunk = {k: float(kept[k]) for k in range(len(bounds)) if kept[k] < 1.0}
    if not shrunk:
        return prog, {}
    ts = cyc.sample_time_s
    u, socs, _ = predict(cell, cur, ts, prog.profile_points[0][1], np.zeros(len(cell.rc)))
    i_max = prog.settings["max_current_a"]
    log_dets = [log_det_information(cell, cur[a:b], ts, amplitude_band(
                    spec, i_max, k, float(cur[a:b].mean())), spec.information)
                if k in shrunk else ld
                for k, ((a, b), ld) in enumerate(zip(bounds, prog.log_dets, strict=True))]
    settings = {**prog.settings,
                "spread_kept_by_sequence": {str(k + 1): kept for k, kept in shrunk.items()}}
    return dataclasses.replace(prog, current_a=cur, voltage_v=u, soc=socs, log_dets=log_dets,
                               settings=settings), shrunk


RANDOM_KINDS = ("prbs", "aprbs")


def random_levels(rng: np.random.Generator, n: int, kind: str) -> np.ndarray:
    """n random levels with zero mean and max |z| = 1: "prbs" two levels (random signs, a
    pseudo-random binary sequence), "aprbs" uniformly distributed amplitudes."""
    if kind == "prbs":
        z = np.where(rng.uniform(0.0, 1.0, n) < 0.5, -1.0, 1.0)
    elif kind == "aprbs":
        z = rng.uniform(-1.0, 1.0, n)
    else:
        raise ValueError(f"random programme kind {kind!r}: expected one of {RANDOM_KINDS}")
    z = z - z.mean()
    return z / max(float(np.abs(z).max()), 1e-12)


def random_programme(cell: CellSpec, cyc: CyclerSpec, spec: DesignSpec,
                     seed: int = 1, kind: str = "aprbs") -> Programme:
    """The comparison: random levels (PRBS or APRBS, fixed seed, zero mean around the
    charge-moving mean) of the same length, hold time, amplitude bands and SoC walk as the
    design; a sequence whose predicted voltage leaves the limits has its spread reduced (that
    sequence only, as the design's constraint acts)."""
    n_seq = sequence_count(spec)
    i_max = current_limit(cell, cyc)
    rng = np.random.default_rng(seed)
    per = round(cyc.hold_s / cyc.sample_time_s)
    n_levels = round(spec.sequence_s / cyc.hold_s)
    lo_v, hi_v = voltage_window(cell, spec)
    soc, v = spec.soc_profile[0], np.zeros(len(cell.rc))
    parts = []
    for k, dsoc in enumerate(allocate(spec.soc_profile, n_seq)[0]):
        z = random_levels(rng, n_levels, kind)      # zero mean: the sequence's charge exactly
        mean = dsoc * cell.capacity_ah * 3600.0 / (n_levels * cyc.hold_s)
        band = amplitude_band(spec, i_max, k, mean)
        for spread in np.linspace(1.0, 0.0, 21):
            cur = np.repeat(mean + z * spread * (band - abs(mean)), per)
            u, socs, v_end = predict(cell, cur, cyc.sample_time_s, soc, v)
            if u.min() >= lo_v and u.max() <= hi_v:
                break
        parts.append(cur)
        soc, v = float(socs[-1]), v_end
    cur = np.concatenate(parts)
    u, socs, _ = predict(cell, cur, cyc.sample_time_s, spec.soc_profile[0], np.zeros(len(cell.rc)))
    time_s = cyc.sample_time_s * np.arange(1, cur.size + 1)
    return Programme(time_s, cur, u, socs, [], [], [], {"random_seed": seed, "kind": kind})


# ----- output -----------------------------------------------------------------------------------
def write_programme(prog: Programme, out: Path) -> list[Path]:
    """Cycler CSV (time_s,current_a: current held until the next row) and BDF CSV."""
    from lmncell.data.readers import write_bdf

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with replaced_whole(out) as part, open(part, "w", encoding="utf-8") as fh:   # no half programme
        fh.write("time_s,current_a\n")
        t_start = np.concatenate([[0.0], prog.time_s[:-1]])
        for t, i in zip(t_start, prog.current_a, strict=True):
            fh.write(f"{float(t)!r},{float(i)!r}\n")
    bdf = out.with_suffix(".bdf.csv")
    write_bdf(prog.to_record(str(out)), bdf)
    meta = out.with_suffix(".json")
    write_text_whole(meta, json_text({"settings": prog.settings,
                                      "profile_points": prog.profile_points,
                                      "log_det_per_sequence": prog.log_dets,
                                      "note": "the BDF voltage is the design model's prediction"},
                                     indent=1))
    return [out, bdf, meta]


def plot_programme(prog: Programme, out_dir: Path, index: int = 0) -> list[Path]:
    """Fig. 5 (one sequence) and Fig. 6 (the whole programme with charge and SoC)."""
    from lmncell.report.plots import plt, save_figure

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    a = prog.sequence_starts[index]
    b = prog.sequence_starts[index + 1] if index + 1 < len(prog.sequence_starts) else None
    t = prog.time_s[a:b] - prog.time_s[a]
    fig, ax = plt.subplots(2, 1, figsize=(9, 5), sharex=True, constrained_layout=True)
    ax[0].step(t, prog.current_a[a:b], where="pre")
    ax[0].set(ylabel="current / A", title=f"designed sequence {index + 1} (D-optimal)")
    ax[1].plot(t, prog.voltage_v[a:b], "k")
    ax[1].set(ylabel="predicted voltage / V", xlabel="time / s")
    files.append(save_figure(fig, out_dir / "fig05_sequence.png"))
    th = prog.time_s / 3600
    charge = np.cumsum(prog.current_a) * (prog.time_s[1] - prog.time_s[0]) / 3600
    fig, ax = plt.subplots(3, 1, figsize=(10, 7), sharex=True, constrained_layout=True)
    ax[0].plot(th, prog.current_a, lw=0.5)
    ax[0].set(ylabel="current / A", title="designed programme")
    ax[1].plot(th, charge, color="tab:orange")
    ax[1].set(ylabel="charge / Ah")
    ax[2].plot(th, 100 * prog.soc, color="tab:green", label="SoC (coulomb counting)")
    if prog.profile_points:
        pts = np.array(prog.profile_points)
        ax[2].plot(pts[:, 0] / 3600, 100 * pts[:, 1], "ko", label="target profile")
    ax[2].set(ylabel="SoC / %", xlabel="time / h")
    ax[2].legend()
    files.append(save_figure(fig, out_dir / "fig06_programme.png"))
    return files
