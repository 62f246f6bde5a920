"""Temperature regions: one set of local models per chamber temperature, split apart by fixed
sigmoids in the gaps between the levels' cell temperatures.

Records at a few chamber temperatures whose cells warm up inside each record (Panasonic 10 and
25 °C: 10.8…18.8 and 22…32.8 °C) give the tree a temperature axis on which the self-heating of
one record looks like a regime: it split the 25 °C data along its own warm-up, which follows
SoC and load, and the model generalised worse (Panasonic 25 °C drive cycles alone, C/20 OCV
test, leave-one-record-out, 20–80 % / whole record mV: partition soc 6.74 / 13.60, soc and
temperature 7.36 / 13.69). Here the only temperature splits are the fixed ones between levels;
within a level the tree splits along SoC and current as it does at one temperature, and the
Arrhenius gain carries the self-heating.
"""

from __future__ import annotations

import itertools

import numpy as np
from lmncell.config import TrainConfig
from lmncell.data.dataset import Segment
from lmncell.identification.prefit import segment_levels, temperature_levels
from lmncell.identification.tree import Design, Tree, fit_leaves, one_step
from lmncell.runtime.model import LmnModel
from lmncell.runtime.step import lmn_temperatures

MIN_WIDTH_K = 0.5        # the fixed sigmoids' smallest width (K)
GAP_WIDTHS = 8.0         # a sigmoid's width is the gap over this: 1.8 % leak at the gap's edges
# (Panasonic 25 + 10 °C, leave-one-record-out, 20–80 % / whole mV: 8, width 0.53 K: 25 °C held
# out 7.21 / 10.91, 10 °C 11.12 / 18.58; 2, width 2.1 K: 8.28 / 12.01 and 11.17 / 25.45)


def region_boundaries(segs: list[Segment], base: LmnModel | None = None
                      ) -> list[tuple[float, float]]:
    """(centre, width) in K of the sigmoid between each pair of neighbouring temperature levels
    (temperature_levels): centred in the gap between the lower level's 99th and the upper
    level's 1st percentile of the temperature the partition takes (the cell temperature plus
    base's core rise, lmn_temperatures; the cell temperature itself without base), width a
    GAP_WIDTHS-th of the gap (at least MIN_WIDTH_K; where the levels' temperatures overlap,
    centred in the overlap)."""
    levels = temperature_levels(segs)
    if len(levels) < 2:
        return []
    per_level: list[list[np.ndarray]] = [[] for _ in levels]
    for s, k in zip(segs, segment_levels(segs), strict=True):
        if s.temperature_c is not None:
            t = np.asarray(s.temperature_c, dtype=float)
            per_level[k].append(t if base is None else lmn_temperatures(base, s.current_a, t))
    out = []
    for low, high in itertools.pairwise(per_level):
        top = float(np.percentile(np.concatenate(low), 99))
        bottom = float(np.percentile(np.concatenate(high), 1))
        out.append((0.5 * (top + bottom), max(abs(bottom - top) / GAP_WIDTHS, MIN_WIDTH_K)))
    return out


def region_weights(base: LmnModel, centre_c: float, width_k: float) -> np.ndarray:
    """Node weights ψ whose sigmoid is 1 below centre_c and 0 above (act = (centre − T)/width)
    in the model's normalised partition coordinates."""
    k = base.partition_variables.index("temperature")
    c, s = float(base.partition_center[k]), float(base.partition_scale[k])
    psi = np.zeros(len(base.partition_variables) + 1)
    psi[0] = (centre_c - c) / width_k
    psi[1 + k] = -s / width_k
    return psi


def temperature_region_tree(tree: Tree, base: LmnModel, design: Design, cfg: TrainConfig,
                            boundaries: list[tuple[float, float]]) -> Tree:
    """The root tree split into one leaf per temperature level and per root (charge and
    discharge with pre_partition current_sign): the warmer side split again at each next
    boundary; then every leaf fitted by least squares weighted with its validity."""
    for centre, width in boundaries:
        psi = region_weights(base, centre, width)
        n = tree.theta.shape[0]
        for leaf in range(n - len(tree.roots), n):       # the warmest leaves, one per root
            tree = tree.split(leaf, psi, tree.theta[leaf], tree.theta[leaf])
    phi, _ = one_step(tree.apply(base), design)
    theta = fit_leaves(design, [design.w_fit * phi[:, j] for j in range(phi.shape[1])], cfg)
    return Tree(tree.roots, tree.weights, tree.children, theta)
