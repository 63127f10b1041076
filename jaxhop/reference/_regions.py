"""Domain and feasible-goal regions in closed form (App. A-B, corrected eqs 45-48).

Relative coordinates: `y_rel = y - py`, `zr = z - h - rho0`. `TemplateRegions` caches what
depends on a template alone (its extreme touchdown velocities, `tan` of its angle limits).
"""

from __future__ import annotations

import math

import numpy as np

from ._model import INF, Hopper, Templates, safe_sqrt, stance_controls


class TemplateRegions:
    """Closed-form regions of one template.

    Attributes:
        t: the template's limits as floats (`v_lo`, ..., `k_hi`).
        corners, mask: the domain's candidate extreme touchdown velocities `(10, 2)` and which
            of them are real (`domain_velocity_extremes` of the JAX path).
    """

    def __init__(self, templates: Templates, i: int, hopper: Hopper):
        self.t = t = templates.row(i)
        self.hopper = hopper
        self.half_length = templates.half_length
        m = hopper.m
        r_lo = math.sqrt(2.0 * t["e_lo"] / m)
        r_hi = math.sqrt(2.0 * t["e_hi"] / m)
        a = np.array([1.0, 1.0, 1.0, 1.0, 1.0, -1.0, 1.0, -1.0, 0.0, 0.0]) * np.array(
            [t["v_lo"], t["v_hi"], t["v_lo"], t["v_hi"], r_lo, r_lo, r_hi, r_hi, 0.0, 0.0])
        r2 = np.array([r_hi, r_hi, r_lo, r_lo, r_lo, r_lo, r_hi, r_hi, r_hi, r_hi]) ** 2
        corners = np.stack([a, -safe_sqrt(r2 - a**2)], axis=1)
        self.tan_lo, self.tan_hi = math.tan(t["th_lo"]), math.tan(t["th_hi"])
        corners[8] = -r_hi * np.array([1.0, self.tan_lo]) / math.sqrt(1.0 + self.tan_lo**2)
        corners[9] = r_hi * np.array([1.0, self.tan_hi]) / math.sqrt(1.0 + self.tan_hi**2)
        norm2 = np.sum(corners**2, axis=1)
        eps = 1e-9
        mask = ((corners[:, 0] >= t["v_lo"] - eps) & (corners[:, 0] <= t["v_hi"] + eps)
                & (corners[:, 1] <= eps) & (norm2 >= r_lo**2 - eps) & (norm2 <= r_hi**2 + eps)
                & (r2 >= a**2 - eps))
        mask[8] &= t["th_lo"] > 0
        mask[9] &= t["th_hi"] < 0
        self.corners, self.mask = corners, mask
        self.active = corners[mask]

    # --- domain D (eqs 38-41) ---

    def domain_contains(self, y_rel, zr, ydot):
        """`Z in D(Phi)` without the collision clause (broadcasts)."""
        t, hp = self.t, self.hopper
        energy = 0.5 * hp.m * ydot**2 + hp.m * hp.g * zr
        y_td = y_rel + ydot * safe_sqrt(2.0 * zr / hp.g)
        l = self.half_length
        return ((ydot >= t["v_lo"]) & (ydot <= t["v_hi"]) & (zr > 0) & (energy >= t["e_lo"])
                & (energy <= t["e_hi"]) & (y_td >= -l) & (y_td <= l))

    def domain_height_bounds(self, ydot):
        """Height interval of D at `ydot` (eq 39) with `zr > 0`; empty outside `RV`."""
        t, hp = self.t, self.hopper
        mg = hp.m * hp.g
        lo = np.maximum((t["e_lo"] - 0.5 * hp.m * ydot**2) / mg, 0.0)
        hi = (t["e_hi"] - 0.5 * hp.m * ydot**2) / mg
        inside = (ydot >= t["v_lo"]) & (ydot <= t["v_hi"])
        return np.where(inside, lo, INF), np.where(inside, hi, -INF)

    # --- feasible goal Gf (eqs 42-50) ---

    def _liftoff_speed_bounds(self, c):
        """`(n, n_active)` intervals of the vertical liftoff speed at `ydot* = c`."""
        t = self.t
        a, b = self.active[:, 0], self.active[:, 1]
        c = c[:, None]
        v2 = a**2 + b**2

        def roots(k):
            p = (k - 1.0) * b
            q = c**2 + (k - 1.0) * a * c - k * v2
            disc = p**2 - 4.0 * q
            r = safe_sqrt(disc)
            return (-p - r) / 2.0, (-p + r) / 2.0, disc >= 0

        _, lo_k, has_lo = roots(t["k_lo"])
        hi_lo, hi_hi, has_hi = roots(t["k_hi"])
        lo = np.maximum(np.where(has_lo, lo_k, 0.0), np.where(has_hi, hi_lo, INF))
        hi = np.where(has_hi, hi_hi, -INF)
        # th >= th_lo <=> a - c >= tan_lo (d - b); th <= th_hi <=> a - c <= tan_hi (d - b).
        big = 1e12
        if abs(self.tan_lo) < big:
            tl = self.tan_lo
            bound = b + (a - c) / (tl if tl != 0 else 1.0)
            if tl < 0:
                lo = np.maximum(lo, bound)
            elif tl > 0:
                hi = np.minimum(hi, bound)
            else:
                hi = np.where(a < c, -INF, hi)
        if abs(self.tan_hi) < big:
            th = self.tan_hi
            bound = b + (a - c) / (th if th != 0 else 1.0)
            if th > 0:
                lo = np.maximum(lo, bound)
            elif th < 0:
                hi = np.minimum(hi, bound)
            else:
                hi = np.where(a > c, -INF, hi)
        return lo, hi

    def goal_height_bounds(self, ydot):
        """Height interval of Gf at each `ydot` (`lo > hi` when empty)."""
        ydot = np.atleast_1d(np.asarray(ydot, float))
        two_g = 2.0 * self.hopper.g
        if self.active.shape[0] == 0:
            return np.full(ydot.shape, INF), np.full(ydot.shape, -INF)
        lo, hi = self._liftoff_speed_bounds(ydot)
        d_lo = np.maximum(np.max(lo, axis=1), 0.0)
        d_hi = np.min(hi, axis=1)
        empty = d_hi <= d_lo
        return np.where(empty, INF, d_lo**2 / two_g), np.where(empty, -INF, d_hi**2 / two_g)

    def goal_position_bounds(self, ydot, zr):
        """`y_rel` interval of Gf at `(ydot, zr)` (eqs 49-50)."""
        t = self.t
        shift = ydot * safe_sqrt(2.0 * zr / self.hopper.g)
        l = self.half_length
        return shift + l + t["dy_lo"], shift - l + t["dy_hi"]

    def goal_velocity_ok(self, ydot, zdot):
        """Liftoff velocity `(ydot, zdot)` reachable from every extreme touchdown velocity."""
        t = self.t
        if self.active.shape[0] == 0:
            return np.zeros(np.shape(ydot), bool)
        v_star = np.stack([ydot, zdot], axis=-1)[..., None, :]
        th, k = stance_controls(self.active, v_star)
        ok = (th >= t["th_lo"]) & (th <= t["th_hi"]) & (k >= t["k_lo"]) & (k <= t["k_hi"])
        return np.all(ok, axis=-1) & (zdot > 0)

    def feasible_goal_contains(self, y_rel, zr, ydot, y_tol=0.0):
        """`Z' in Gf(Phi)` by the closed form (broadcasts); `y_tol` widens the `y` interval."""
        zdot = safe_sqrt(2.0 * self.hopper.g * zr)
        lo, hi = self.goal_position_bounds(ydot, zr)
        return (self.goal_velocity_ok(ydot, zdot) & (y_rel >= lo - y_tol)
                & (y_rel <= hi + y_tol) & (zr > 0))


def linspace(start: float, stop: float, num: int) -> np.ndarray:
    """`linspace` computed as the JAX path does (`start (1 - s) + stop s`, `s = i * (1/div)`)."""
    div = num - 1
    step = np.arange(div) * (1.0 / div)
    return np.concatenate([start * (1 - step) + stop * step, [stop]])


def template_boxes(regions: list[TemplateRegions], n_grid: int = 2001):
    """Bounding boxes of Gf and D per template (relative `(y, zr, ydot)` rows, `(lo, hi)`)."""
    gfs, ds = [], []
    for reg in regions:
        t, hp = reg.t, reg.hopper
        r_hi = math.sqrt(2.0 * t["e_hi"] / hp.m)
        v = linspace(-1.0, 1.0, n_grid) * max(t["k_hi"], 1.0) * r_hi * 1.05
        zl, zh = reg.goal_height_bounds(v)
        ok = zh >= zl
        step = v[1] - v[0]
        v_lo, v_hi = v[ok].min() - step, v[ok].max() + step
        z_lo = max(zl[ok].min() - 1e-3, 0.0)
        z_hi = zh[ok].max() + 1e-3
        ylo, yhi = reg.goal_position_bounds(np.array([v_lo, v_lo, v_hi, v_hi]),
                                            np.array([z_lo, z_hi, z_lo, z_hi]))
        gfs.append([[ylo.min(), yhi.max()], [z_lo, z_hi], [v_lo, v_hi]])
        dvl, dvh = t["v_lo"], t["v_hi"]
        vmax2 = max(dvl**2, dvh**2)
        vmin2 = 0.0 if dvl <= 0 <= dvh else min(dvl**2, dvh**2)
        mg = hp.m * hp.g
        dz_lo = max((t["e_lo"] - 0.5 * hp.m * vmax2) / mg, 0.0)
        dz_hi = (t["e_hi"] - 0.5 * hp.m * vmin2) / mg
        shift = np.array([dvl, dvh])[:, None] * safe_sqrt(
            2.0 * np.array([dz_lo, dz_hi]) / hp.g)[None, :]
        l = reg.half_length
        ds.append([[-l - shift.max(), l - shift.min()], [dz_lo, dz_hi], [dvl, dvh]])
    return np.asarray(gfs, float), np.asarray(ds, float)
