"""A virtual cell to judge experiment designs when pybamm is absent: a nonlinear equivalent
circuit with hysteresis, deliberately richer than the linear design model.

u = OCV(SoC) + M·h + R0(SoC, i)·i + Σ_m v_m, with
R0(SoC, i) = R0·(1 + 0.6·(1 − SoC)²)·asinh(i/(2·i0))/(i/(2·i0)) (a Butler–Volmer-like drop),
three RC branches with SoC-dependent resistance (τ = 8 s, 120 s, 1500 s), a one-state hysteresis
h (rate γ, amplitude M) and 1 mV Gaussian measurement noise with a fixed seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from lmncell.design.optimal import DEFAULT_OCV_SOC, DEFAULT_OCV_V, held_soc
from lmncell.identification.baselines import hysteresis


@dataclass
class VirtualCell:
    capacity_ah: float = 2.3
    r0_ohm: float = 0.010
    i0_a: float = 8.0
    rc: tuple = ((0.006, 8.0), (0.010, 120.0), (0.015, 1500.0))
    hyst_v: float = 0.012
    gamma: float = 80.0
    noise_v: float = 0.001
    seed: int = 7

    def run(self, current_a: np.ndarray, soc0: float, ts: float = 1.0,
            name: str = "programme") -> tuple[np.ndarray, np.ndarray]:
        """Terminal voltage (V, with noise) and SoC for a current held over each sample (name:
        unused here; the PyBaMM cell names the run in its errors)."""
        soc = held_soc(soc0, current_a, ts, self.capacity_ah)
        x = current_a / (2.0 * self.i0_a)
        bv = np.where(np.abs(x) > 1e-9, np.arcsinh(x) / np.where(x == 0, 1, x), 1.0)
        u = np.interp(soc, DEFAULT_OCV_SOC, DEFAULT_OCV_V)
        u = u + self.r0_ohm * (1 + 0.6 * (1 - soc) ** 2) * bv * current_a
        for k, (r, tau) in enumerate(self.rc):
            e = np.exp(-ts / tau)
            r_soc = r * (1 + (0.8 if k == 2 else 0.3) * (1 - soc) ** 2)
            v = np.empty_like(current_a)
            acc = 0.0
            for n, (rr, i) in enumerate(zip(r_soc.tolist(), current_a.tolist(), strict=True)):
                acc = e * acc + rr * (1 - e) * i
                v[n] = acc
            u = u + v
        u = u + self.hyst_v * hysteresis(current_a, self.gamma, ts, self.capacity_ah, 0.0)
        rng = np.random.default_rng(self.seed)
        return u + rng.normal(0.0, self.noise_v, u.size), soc

    def ocv_test(self, c_rate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A slow round trip at c_rate from full: a full discharge then a full charge (1 s
        samples); time (s), current (A, > 0 charges) and voltage (V, with noise)."""
        n = round(3600.0 / c_rate)
        i = c_rate * self.capacity_ah
        cur = np.concatenate([np.full(n, -i), np.full(n, i)])
        u, _ = self.run(cur, 1.0, name="OCV test")
        return np.arange(1, cur.size + 1, dtype=float), cur, u

    def describe(self) -> str:
        return "built-in nonlinear ECM with hysteresis (lmncell.design.virtual_cell)"
