"""Proof of an experiment design on a virtual cell: LMNs trained on the designed programme and on
random programmes (PRBS and APRBS, several seeds, same length, hold time, amplitude bands, charge
and limits), each validated in free run on drive profiles run on the same virtual cell.

The flow, as an engineer would run it on a new cell: a slow OCV test and a pulse test on the
virtual cell give the linear design model (OCV, R0, RC elements and the resistance over SoC,
`characterise`); the
programme is designed on that model; every programme and every validation profile is run on the
virtual cell (PyBaMM's DFN, or the built-in nonlinear ECM). Current > 0 charges; SI units.
"""

from __future__ import annotations

import dataclasses
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
from lmncell.data.records import DataError, Record, RecordMeta
from lmncell.design import CAPACITY_TOLERANCE, VIRTUAL_CELLS
from lmncell.design.optimal import (
    RANDOM_KINDS,
    CellSpec,
    CyclerSpec,
    DesignSpec,
    Programme,
    current_limit,
    log_det_information,
    predict,
    random_programme,
    voltage_window,
)
from lmncell.design.pybamm_cell import VirtualCellRunError

if TYPE_CHECKING:
    from lmncell.config import TrainConfig
    from lmncell.data.dataset import Segment

RANDOM_SEEDS = (1, 2, 3, 4, 5)
OCV_TEST_C_RATE = 1 / 20
PULSE_C_RATES = (3.0,)     # characterisation pulses, C
DESIGN_PROOF_OE_RIDGE = 1e-3  # the proof's LMNs: a numerical refinement ridge only
PULSE_S, PULSE_REST_S = 30, 120
NEGLIGIBLE_RC = 0.05                 # an RC element below this share of R0 is dropped


class VirtualCellLike(Protocol):
    """What a virtual cell offers the proof (PybammCell, VirtualCell)."""

    capacity_ah: float

    def run(self, current_a: np.ndarray, soc0: float, ts: float = 1.0,
            name: str = "programme") -> tuple[np.ndarray, np.ndarray]: ...

    def ocv_test(self, c_rate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def describe(self) -> str: ...


def make_virtual_cell(kind: str, capacity_ah: float) -> VirtualCellLike:
    """The virtual cell named by --virtual-cell."""
    if kind == "pybamm":
        from lmncell.design.pybamm_cell import PybammCell, require_pybamm

        require_pybamm()
        return PybammCell(capacity_ah=capacity_ah)
    if kind == "builtin":
        from lmncell.design.virtual_cell import VirtualCell

        return VirtualCell(capacity_ah=capacity_ah)
    raise DataError(f"--virtual-cell {kind!r}: expected one of {', '.join(VIRTUAL_CELLS)}")


# ----- characterisation: the design model from tests on the cell ------------------------------
def ocv_test_record(vc: VirtualCellLike, capacity_ah: float, folder: Path) -> Path:
    """A slow full → empty → full test run on the virtual cell, written as a BDF file;
    DataError where its discharge delivers a capacity other than capacity_ah (Ah)."""
    from lmncell.data.readers import write_bdf
    from lmncell.data.soc import ocv_from_round_trip

    t, cur, u = vc.ocv_test(OCV_TEST_C_RATE)
    test = Record(t, cur, u, RecordMeta("virtual cell C/20 OCV test", "virtual",
                                        "current > 0 charges", float(t[1] - t[0])))
    delivered = ocv_from_round_trip(test).capacity_ah    # as training reads a round trip
    if abs(delivered / capacity_ah - 1.0) > CAPACITY_TOLERANCE:
        raise DataError(f"--capacity {capacity_ah:g} Ah: the virtual cell ({vc.describe()}) "
                        f"delivers {delivered:.3f} Ah in its C/20 discharge from full to "
                        f"{float(u.min()):.2f} V, more than {100 * CAPACITY_TOLERANCE:g} % "
                        "apart; the proof designs on the virtual cell: give --capacity "
                        f"{delivered:.2f}")
    path = Path(folder) / "virtual_ocv_test.bdf.csv"
    write_bdf(test, path)
    return path


def pulse_current(capacity_ah: float, c_rates: tuple[float, ...] = PULSE_C_RATES) -> np.ndarray:
    """Discharge and charge pulses (PULSE_S each, PULSE_REST_S rest after each) at each C-rate."""
    parts = [np.zeros(PULSE_REST_S)]
    for c in c_rates:
        for sign in (-1.0, 1.0):
            parts += [np.full(PULSE_S, sign * c * capacity_ah), np.zeros(PULSE_REST_S)]
    return np.concatenate(parts)


@dataclass
class Characterisation:
    cell: CellSpec
    rmse_mv: float
    pulse_socs: tuple[float, ...]


def characterise(vc: VirtualCellLike, cell: CellSpec, spec: DesignSpec,
                 ocv_path: Path) -> Characterisation:
    """The design model of this cell: OCV = mean branch of the slow test; R0, R1, τ1, R2, τ2
    and a resistance factor at each end of the SoC profile (1 in the middle) fitted (least
    squares on log-parameters, one OCV offset per run) to pulse tests at the profile's low end,
    middle and high end: the cell's resistance rises towards empty, and a design model without
    that would plan pulses the cell cannot take there."""
    from lmncell.identification.ocvfit import measured_ocv
    from scipy.optimize import least_squares

    knots = np.linspace(0.0, 1.0, 41)
    ocv_v = measured_ocv([str(ocv_path)], cell.capacity_ah, knots)
    base = dataclasses.replace(cell, ocv_soc=tuple(knots), ocv_v=tuple(float(v) for v in ocv_v))
    lo, hi = min(spec.soc_profile), max(spec.soc_profile)
    socs = (lo, 0.5 * (lo + hi), hi)
    cur = pulse_current(cell.capacity_ah)
    runs = [(s, vc.run(cur, s, name=f"pulse test at SoC {s:.2f}")[0]) for s in socs]

    def model_cell(p: np.ndarray) -> CellSpec:
        r0, r1, t1, r2, t2, g_lo, g_hi = np.exp(p)
        return dataclasses.replace(base, r0_ohm=float(r0),
                                   rc=[(float(r1), float(t1)), (float(r2), float(t2))],
                                   r_scale_soc=socs, r_scale=(float(g_lo), 1.0, float(g_hi)))

    def residual(p: np.ndarray) -> np.ndarray:
        c = model_cell(p)
        res = []
        for s, u in runs:
            e = u - predict(c, cur, 1.0, s, np.zeros(len(c.rc)))[0]
            res.append(e - e.mean())
        return np.concatenate(res)

    p0 = np.log([cell.r0_ohm, *cell.rc[0], *cell.rc[1], 1.0, 1.0])
    lower = np.log([1e-5, 1e-5, 1.0, 1e-5, 30.0, 0.2, 0.2])       # τ1 1…30 s, τ2 30…600 s
    upper = np.log([1.0, 1.0, 30.0, 1.0, 600.0, 5.0, 5.0])
    fit = least_squares(residual, np.clip(p0, lower + 1e-9, upper - 1e-9), bounds=(lower, upper))
    rmse = float(np.sqrt(np.mean(fit.fun ** 2)))
    fitted = model_cell(fit.x)
    # an RC element with a negligible resistance has no information to design for: the
    # D-criterion would chase its vanishing sensitivities (the DFN's 3C pulses: one RC)
    rc = [(r, t) for r, t in fitted.rc if r >= NEGLIGIBLE_RC * fitted.r0_ohm] or fitted.rc[:1]
    return Characterisation(dataclasses.replace(fitted, rc=rc), 1e3 * rmse, socs)


# ----- validation profiles ---------------------------------------------------------------------
def drive_profile_current(capacity_ah: float, cycle: str = "udds", repeat: int = 3,
                          c_rate_peak: float = 4.0) -> np.ndarray:
    """Cell current (A, 1 s) of a vehicle drive cycle scaled so that its peak is c_rate_peak·C."""
    from lmncell.scenarios.drive import load_vehicle, pack_power
    from lmncell.scenarios.traces import load_cycle

    veh = load_vehicle()
    trace = load_cycle(cycle)
    p = np.tile(pack_power(veh, trace.speed_mps, trace.grade, trace.step_s), repeat)
    cur = -p / (3.3 * veh.n_series * veh.n_parallel)
    return cur * c_rate_peak * capacity_ah / np.abs(cur).max()


def hev_profile_current(capacity_ah: float, c_rate_peak: float, cycle: str = "udds",
                        repeat: int = 3) -> np.ndarray:
    """Charge-sustaining (hybrid) use of a drive cycle: its mean removed, peak c_rate_peak·C."""
    cur = drive_profile_current(capacity_ah, cycle, repeat, c_rate_peak)
    cur = cur - cur.mean()
    return cur * c_rate_peak * capacity_ah / np.abs(cur).max()


def pulse_profile_current(capacity_ah: float, c_rate_peak: float, blocks: int = 10) -> np.ndarray:
    """High-rate pulses walking down through SoC: per block a 10 s discharge and a 10 s charge
    pulse (40 s rest after each) at an amplitude cycling through 40, 70 and 100 % of the peak,
    then 180 s at 1C discharge (−5 % SoC)."""
    parts = []
    for b in range(blocks):
        a = c_rate_peak * capacity_ah * (0.4, 0.7, 1.0)[b % 3]
        parts += [np.full(10, -a), np.zeros(40), np.full(10, a), np.zeros(40),
                  np.full(180, -capacity_ah)]
    return np.concatenate(parts)


def largest_safe_peak(cell: CellSpec, spec: DesignSpec, shape, soc0: float,
                      c_rate_max: float) -> float:
    """The largest peak C-rate (from c_rate_max down in steps of 10 %) whose profile the design
    model keeps inside the voltage limits with the design's margin: validation runs the cell
    where a user may run it."""
    lo, hi = voltage_window(cell, spec)
    for frac in np.linspace(1.0, 0.1, 10):
        c = c_rate_max * frac
        u = predict(cell, shape(c), 1.0, soc0, np.zeros(len(cell.rc)))[0]
        if u.min() >= lo and u.max() <= hi:
            return float(c)
    return float(c_rate_max * 0.1)


@dataclass
class Profile:
    key: str
    description: str
    current_a: np.ndarray
    soc0: float


def validation_profiles(cell: CellSpec, cyc: CyclerSpec, spec: DesignSpec) -> list[Profile]:
    """Three profiles: EV discharge (UDDS x3 through the vehicle model, from the profile's top),
    charge-sustaining hybrid use (UDDS x3, mean removed, mid profile) and high-rate pulses
    walking down from the top; each at the largest peak (≤ the design's current limit, ≤ 4C for
    the EV) that the design model keeps within the voltage limits."""
    cap = cell.capacity_ah
    c_lim = current_limit(cell, cyc) / cap
    top, bottom = max(spec.soc_profile), min(spec.soc_profile)
    mid = 0.5 * (top + bottom)
    shapes = [("ev_discharge", "EV discharge: UDDS x3 through the vehicle model",
               lambda c: drive_profile_current(cap, c_rate_peak=c), top, min(4.0, c_lim)),
              ("hev_sustaining", "charge-sustaining hybrid: UDDS x3, mean removed",
               lambda c: hev_profile_current(cap, c), mid, c_lim),
              ("high_rate_pulses", "high-rate pulses (10 s, 40/70/100 % of the peak) walking "
               "down 50 % SoC", lambda c: pulse_profile_current(cap, c), top, c_lim)]
    out = []
    for key, text, shape, s0, c_max in shapes:
        c = largest_safe_peak(cell, spec, shape, s0, c_max)
        out.append(Profile(key, f"{text}, peak {c:.1f}C, from SoC {s0:.2f}", shape(c), s0))
    return out


# ----- the comparison --------------------------------------------------------------------------
def compare_on_virtual_cell(designed: Programme, cell: CellSpec, cyc: CyclerSpec,
                            spec: DesignSpec, vc: VirtualCellLike, ocv_path: Path,
                            progress=print, seeds: tuple[int, ...] = RANDOM_SEEDS,
                            kinds: tuple[str, ...] = RANDOM_KINDS) -> dict:
    """Train an LMN on each programme run on vc (with the OCV test ocv_path), validate each in
    free run on the validation profiles run on vc. Returns per profile designed_mv and the lists
    prbs_mv / aprbs_mv (whole-record RMSE, mV), and per programme its model and log det."""
    from lmncell.data.dataset import Segment

    def segment(name: str, cur: np.ndarray, s0: float) -> Segment:
        u, soc = vc.run(cur, s0, name=name)
        t = np.arange(1, cur.size + 1, dtype=float)
        return Segment(name, t, cur, u, None, s0, soc, np.ones(cur.size),
                       temperature_kind="none")

    soc0 = float(spec.soc_profile[0])
    profiles = validation_profiles(cell, cyc, spec)
    vals = {p.key: segment(p.description, p.current_a, p.soc0) for p in profiles}
    progress("  validation profiles run on the virtual cell: "
             + "; ".join(p.description for p in profiles))
    same_hold = dataclasses.replace(cyc, hold_s=designed.settings["cycler"]["hold_s"])
    programmes = [("designed", designed.current_a)] + [
        (f"{kind}_seed_{s}", random_programme(cell, same_hold, spec, s, kind).current_a)
        for kind in kinds for s in seeds]
    cfg = _proof_config(ocv_path)
    rows: dict = {}
    skipped: dict[str, str] = {}
    for name, cur in programmes:
        try:
            seg = segment(name, cur, soc0)
        except VirtualCellRunError as exc:
            if name == "designed":
                raise
            # a random programme is held inside the limits on the design model only; where
            # the cell itself leaves them it cannot be run, and is left out of the medians
            skipped[name] = str(exc)
            progress(f"  {name}: not compared, the virtual cell cannot run it ({exc})")
            continue
        rows[name] = _programme_row(seg, cfg, cell, cyc.sample_time_s, spec.information, vals)
        progress(f"  {name}: {rows[name]['local_models']} local models, free-run RMSE "
                 + ", ".join(f"{k} {rows[name][f'{k}_mv']:.2f} mV" for k in vals))
    return summarise(rows, profiles, kinds, skipped)


def _proof_config(ocv_path: Path) -> TrainConfig:
    """The training settings of the proof. Free local models, no offset ridge and only a
    numerical refinement ridge (oe_ridge): the design maximises the information of the
    unconstrained least-squares estimator, which the RC-ladder bounds or a ridge on the
    coefficients or the local OCV offsets (parameters of that information) would replace by
    another one."""
    from lmncell.config import load_config

    return load_config(partition=["soc", "current"], validation="none", stop="aicc",
                       max_local_models=8, ocv_tests=[str(ocv_path)], local_model_form="free",
                       offset_ridge=0.0, oe_ridge=DESIGN_PROOF_OE_RIDGE)


def _programme_row(seg: Segment, cfg: TrainConfig, cell: CellSpec, sample_time_s: float,
                   information: str, vals: dict[str, Segment]) -> dict:
    """The LMN trained on one programme's run (seg): its local models, the programme's peak
    current (A) and log det of its information, and its whole-record free-run RMSE (mV) on
    each validation profile's run ("<key>_mv")."""
    from lmncell.evaluation.evaluate import simulate_segment
    from lmncell.evaluation.metrics import record_metrics
    from lmncell.identification.construction import train_lmn

    res = train_lmn([seg], cfg, cell.capacity_ah)
    row = {"local_models": res.chosen_m, "peak_current_a": float(np.abs(seg.current_a).max()),
           "log_det_information": log_det_information(cell, seg.current_a, sample_time_s,
                                                      information=information)}
    for key, val in vals.items():
        sim = simulate_segment(res.model, val)
        row[f"{key}_mv"] = record_metrics(val.voltage_v, sim.voltage_v, val.soc_ref)["rmse_mv"]
    return row


def summarise(rows: dict, profiles: list[Profile], kinds: tuple[str, ...],
              skipped: dict[str, str] | None = None) -> dict:
    """Per profile: designed_mv, <kind>_mv lists, medians and whether the design beats them;
    per kind the covariance-determinant ratio (random over designed, design model); skipped:
    the random programmes the virtual cell could not run, and why. A kind none of whose
    programmes ran has no median (None) and no ratio, and the design is not said to beat it."""
    des = rows["designed"]
    out: dict = {"profiles": {}, "covariance_det_ratio": {}, "random_kinds": list(kinds),
                 "programmes": rows, "skipped": dict(skipped or {})}
    ran = {kind: [r for n, r in rows.items() if n.startswith(f"{kind}_")] for kind in kinds}
    for p in profiles:
        entry: dict = {"description": p.description, "designed_mv": des[f"{p.key}_mv"]}
        for kind in kinds:
            vals = [r[f"{p.key}_mv"] for r in ran[kind]]
            med = float(np.median(vals)) if vals else None
            entry[f"{kind}_mv"] = vals
            entry[f"{kind}_median_mv"] = med
            entry[f"beats_{kind}_median"] = med is not None and bool(des[f"{p.key}_mv"] < med)
        out["profiles"][p.key] = entry
    for kind in kinds:
        if ran[kind]:
            ld = np.median([r["log_det_information"] for r in ran[kind]])
            out["covariance_det_ratio"][f"{kind}_over_designed"] = float(
                np.exp(des["log_det_information"] - ld))
    out["designed_beats_every_median"] = all(
        e[f"beats_{k}_median"] for e in out["profiles"].values() for k in kinds)
    return out


def prove_design(vc: VirtualCellLike, cell: CellSpec, cyc: CyclerSpec, spec: DesignSpec,
                 design, progress=print, seeds: tuple[int, ...] = RANDOM_SEEDS) -> tuple[dict,
                                                                                          Programme]:
    """Characterise vc, design on the characterised model (design(cell) → Programme), compare."""
    with tempfile.TemporaryDirectory() as tmp:
        progress("characterising the virtual cell: slow OCV test and pulse tests …")
        ocv_path = ocv_test_record(vc, cell.capacity_ah, Path(tmp))
        ch = characterise(vc, cell, spec, ocv_path)
        c = ch.cell
        progress(f"  design model: R0 {1e3 * c.r0_ohm:.2f} mΩ, RC "
                 + ", ".join(f"{1e3 * r:.2f} mΩ / {t:.1f} s" for r, t in c.rc)
                 + ", resistance × " + ", ".join(
                     f"{g:.2f} at SoC {s:.2f}"
                     for s, g in zip(c.r_scale_soc, c.r_scale, strict=True))
                 + f"; pulse-fit RMSE {ch.rmse_mv:.2f} mV")
        prog = design(c)
        result = compare_on_virtual_cell(prog, c, cyc, spec, vc, ocv_path, progress, seeds)
    result["virtual_cell"] = vc.describe()
    result["design_model"] = {"r0_ohm": c.r0_ohm, "rc": [list(x) for x in c.rc],
                              "resistance_scale": dict(zip(map(str, c.r_scale_soc), c.r_scale,
                                                          strict=True)),
                              "pulse_fit_rmse_mv": ch.rmse_mv,
                              "pulse_socs": list(ch.pulse_socs)}
    if hasattr(vc, "solves"):       # the PyBaMM cell's record of every solve
        result["solves"] = vc.solves
    return result, prog


def _left_out_text(result: dict) -> str:
    """The proof figure's note of the random programmes the virtual cell could not run, counted
    per kind ("left out, the cell could not run them: 5 of 5 PRBS, 1 of 5 APRBS"), a line of the
    title that fits whatever their number; their names and reasons are in the proof JSON."""
    skipped = result.get("skipped") or {}
    if not skipped:
        return ""
    counts = []
    for kind in result["random_kinds"]:
        n_skipped = sum(name.startswith(f"{kind}_") for name in skipped)
        n_ran = sum(name.startswith(f"{kind}_") for name in result["programmes"])
        if n_skipped:
            counts.append(f"{n_skipped} of {n_skipped + n_ran} {kind.upper()}")
    return f"\nleft out, the cell could not run them: {', '.join(counts)}"


def plot_proof(result: dict, out_dir: Path, stem: str = "design") -> Path:
    """Per validation profile the designed programme's free-run RMSE beside every random
    programme's (dots) and their medians (bars); the title gives the covariance ratios."""
    from lmncell.report.plots import plt, save_figure

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    profs = result["profiles"]
    kinds = result["random_kinds"]
    fig, ax = plt.subplots(figsize=(9, 4.5), constrained_layout=True)
    width = 0.8 / (len(kinds) + 1)
    for j, key in enumerate(profs):
        e = profs[key]
        ax.bar(j, e["designed_mv"], width, color="tab:blue", label="designed" if j == 0 else None)
        for m, kind in enumerate(kinds, start=1):
            x = j + m * width
            if e[f"{kind}_median_mv"] is not None:     # None: none of that kind ran
                ax.bar(x, e[f"{kind}_median_mv"], width, color=f"C{m}", alpha=0.5,
                       label=f"{kind.upper()} median" if j == 0 else None)
            ax.plot([x] * len(e[f"{kind}_mv"]), e[f"{kind}_mv"], "k.", ms=4,
                    label="each random programme" if j == 0 and m == 1 else None)
    ax.set_xticks([j + 0.4 - width / 2 for j in range(len(profs))], list(profs))
    ax.set_yscale("log")
    ax.set_ylabel("free-run voltage RMSE on the profile / mV")
    ratios = ", ".join(f"{k.split('_')[0].upper()} {v:.3g}"
                       for k, v in result["covariance_det_ratio"].items())
    cell = result.get("virtual_cell", "virtual cell").split(",")[0].split(";")[0]
    left_out = _left_out_text(result)
    ax.set_title(f"LMNs trained on each programme run on {cell}, validated in free run\n"
                 f"information-determinant ratio designed/random (median): {ratios}{left_out}",
                 fontsize=9)
    ax.legend(fontsize=8)
    path = out_dir / f"{stem}_proof.png"
    return save_figure(fig, path)
