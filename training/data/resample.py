"""Resampling records to the model's fixed sample time.

Convention (the same as the FMU's): sample k of a resampled record sits at the end of the step
[t_k − Ts, t_k]; current, voltage and temperature are the means over that step of the measured
signal, taken as the mean of its two end samples over each sample interval (the trapezoid rule's
integral, interpolated linearly), so the model sees the current held over the step and is compared
with the mean measured voltage over it. SoC and charge counters are taken at t_k.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from lmncell.data.records import DataError, Record


def _cumulative(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(t))])


def _step_means(t: np.ndarray, x: np.ndarray, grid: np.ndarray, ts: float,
                delay_s: float = 0.0) -> np.ndarray:
    """Means of x over [g − Ts − δ, g − δ] for each grid time g (δ = delay_s; before the first
    sample the first interval's mean is held, as an FMU holds its first input there)."""
    F = _cumulative(t, x)
    if not delay_s:
        return (np.interp(grid, t, F) - np.interp(grid - ts, t, F)) / ts
    first = 0.5 * (x[0] + x[1]) if len(x) > 1 else x[0]

    def integral(tau: np.ndarray) -> np.ndarray:
        return np.interp(tau, t, F) + first * np.minimum(tau - t[0], 0.0)

    return (integral(grid - delay_s) - integral(grid - ts - delay_s)) / ts


def resample_segment(rec: Record, sample_time_s: float, current_delay_s: float = 0.0) -> Record:
    """One gap-free record on a fixed grid t0+Ts, t0+2Ts, … (means over each step; the current's
    over the step δ = current_delay_s earlier, as a model with that delay takes it)."""
    ts = float(sample_time_s)
    if not ts > 0:
        raise DataError(f"{rec.meta.source}: sample_time_s={ts!r}; expected > 0 s")
    t = rec.time_s
    n = int(np.floor((t[-1] - t[0]) / ts + 1e-9))
    if n < 2:
        raise DataError(f"{rec.meta.source}: {rec.duration_s:.3f} s is shorter than two steps of "
                        f"{ts} s")
    grid = t[0] + ts * np.arange(1, n + 1)

    def mean(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else _step_means(t, a, grid, ts)

    def at(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else np.interp(grid, t, a)

    meta = dataclasses.replace(rec.meta, sample_time_s=ts, segment_starts=[0], first_line=None,
                               notes=[*rec.meta.notes, f"resampled to {ts} s (step means)"])
    current = _step_means(t, rec.current_a, grid, ts, current_delay_s)
    return Record(grid, current, _step_means(t, rec.voltage_v, grid, ts), meta,
                  temperature_c=mean(rec.temperature_c), soc_ref=at(rec.soc_ref),
                  charge_ah=at(rec.charge_ah), ambient_c=mean(rec.ambient_c))


def resample(rec: Record, sample_time_s: float, current_delay_s: float = 0.0) -> list[Record]:
    """Each gap-free segment of a record resampled to sample_time_s (segments stay separate)."""
    return [resample_segment(seg, sample_time_s, current_delay_s) for seg in rec.segments()
            if seg.duration_s >= 2 * sample_time_s]


def find_gaps(time_s: np.ndarray, factor: float = 20.0, current_a: np.ndarray | None = None,
              charge_ah: np.ndarray | None = None, tol_ah: float = 1e-3,
              long_s: float = 600.0) -> np.ndarray:
    """Indices k where data is missing between samples k−1 and k.

    A step longer than factor × the median step is a gap unless the data show that nothing was
    lost: the tester's charge counter moved as the held current explains (within tol_ah), or, with
    no counter, the step is shorter than long_s and the cell rested on both sides (a slower
    logging rate during a rest) or the current on each side would move less than tol_ah over
    it (the Panasonic drive cycles' 2-s pauses between schedule steps at −0.07 A: 0.04 mAh).
    """
    dt = np.diff(time_s)
    if dt.size == 0:
        return np.array([], dtype=int)
    cand = np.flatnonzero(dt > factor * max(float(np.median(dt)), 1e-9))
    if current_a is None:
        return cand + 1
    held_ah = current_a[cand] * dt[cand] / 3600.0
    if charge_ah is not None:
        lost = np.abs(np.diff(charge_ah)[cand] - held_ah) > tol_ah + 0.02 * np.abs(held_ah)
    else:
        larger = np.maximum(np.abs(current_a[cand]), np.abs(current_a[cand + 1]))
        quiet = (larger < 0.02) | (larger * dt[cand] / 3600.0 < tol_ah)
        lost = ~quiet | (dt[cand] > long_s)
    return cand[lost] + 1
