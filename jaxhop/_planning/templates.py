"""Stride policy templates (eq 4, eq 33): data, not code."""

from __future__ import annotations

import dataclasses
import itertools
import math
from types import SimpleNamespace

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._core.errors import InputError
from .._core.params import REFERENCE_HOPPER, froude_scales
from .._core.terrain import SEGMENT_LENGTH

_FIELDS = ("v_lo", "v_hi", "e_lo", "e_hi", "dy_lo", "dy_hi", "th_lo", "th_hi", "k_lo", "k_hi")


def eq37_lead(ydot, coefficients):
    """`Y` of eq 37 from `coefficients = (L, sin(theta_avg), V |v_max|)` (a tuple, or the
    traced array `Templates.lead`): `L (ydot sin(theta_avg) / (V |v_max|))`."""
    length, sin_theta, speed_max = coefficients[0], coefficients[1], coefficients[2]
    return length * (ydot * sin_theta / speed_max)


@dataclasses.dataclass(frozen=True)
class SlipAdjust:
    """SLIP adjustments of BHop templates (section VII-A, eqs 35-37), at any hopper size.

    Why and how they were refitted: `docs/decisions.md`, "SLIP on BHop plans".

    `h(v) = cm (atan(c (v + co)) / pi - cs)` with `c = ca` for `v < co`, `cb` otherwise;
    the horizontal shift of a stride is limited to `[h(ydot_avg), -h(-ydot_avg)]` (eq 35),
    which replaces the template's own `dy` range. The printed eq 35 has `cs = 1 - co`; with
    the printed constants (`SlipAdjust.printed()`) the limits are about `[-1.5, -0.7]` and
    `[0.7, 1.5]` m, which no template range ever meets, so the defaults are refitted to
    SLIP strides (docs/decisions.md, "SLIP on BHop plans"; `docs/slip_shift_fit.py`).

    The constants are in the units of `REFERENCE_HOPPER` (80 kg, 9.81 m/s^2, 1 m): metres
    and m/s of that hopper. `rho0` and `g` name the hopper the adjustments apply to
    (`for_hopper`); by Froude similarity its strides are the reference hopper's with
    lengths times `L = rho0 / 1 m` and speeds times `V = sqrt(g rho0 / (9.81 m/s^2 1 m))`,
    so `h(v) = L h_ref(v / V)` and `Y = L Y_ref(ydot / V)`. The mass does not enter (with
    the controls `kc rho0 / (m g)` and `kd / kc` bounded as dimensionless numbers, a
    stride does not depend on it). For the reference hopper `L = V = 1.0` exactly and every
    value is bit for bit the unscaled formula's.

    Attributes:
        theta_avg: average touchdown angle at full speed (rad): the foot lands
            `Y = L ydot sin(theta_avg) / (V v_max)` ahead of where the BHop foot would
            (eq 37; `ydot sin(theta_avg) / v_max` for the reference hopper), which shifts
            every domain's `y` range by `-Y` (eq 36).
        v_max: `|ydot_max|` of eq 37, the largest template speed (reference m/s).
        cm, ca, cb, co, cs: the constants of `h` (reference m and m/s).
        reversal: also forbid a shift past the foot for strides that reverse direction
            (forward to backward: `dy <= 0`; backward to forward: `dy >= 0`), which no
            SLIP stance can do (`slip_shift_limits`; docs/decisions.md, "Reversal rule").
        keep_direction: also forbid, for strides that keep their direction, a goal behind
            the COM's touchdown point (forward strides) or ahead of it (backward): a stance
            that starts and ends moving forward moves forward all along
            (`slip_shift_limits`; docs/decisions.md, "Direction rule").
        direction_slack: how far behind the touchdown the direction rule still lets a
            goal lie, in segment lengths (0 for the plan's policies; goal policies use 1,
            `jaxhop._planning.policies.goal_policy_margin`).
        rho0, g: leg length (m) and gravity (m/s^2) of the hopper the adjustments are
            scaled to (default: the reference hopper's).
    """

    theta_avg: float = 0.2
    v_max: float = 2.5
    cm: float = 0.659
    ca: float = 2.018
    cb: float = 2.018
    co: float = -1.149
    cs: float = 0.2252
    reversal: bool = True
    keep_direction: bool = True
    direction_slack: float = 0.0
    rho0: float = REFERENCE_HOPPER[2]
    g: float = REFERENCE_HOPPER[1]

    @classmethod
    def printed(cls, **kwargs) -> SlipAdjust:
        """The constants as printed in the paper (`Cm = 1.11, Ca = 1, Cb = 10, Co = -0.1`)."""
        return cls(cm=1.11, ca=1.0, cb=10.0, co=-0.1, cs=1.1, reversal=False, keep_direction=False,
                   **kwargs)

    def for_hopper(self, hopper) -> SlipAdjust:
        """The same adjustments scaled to `hopper` (anything with `g`, `rho0`; `m` unused).

        The constants stay in reference units; only the scale changes, so scaling twice
        gives the scaling to the last hopper.
        """
        return dataclasses.replace(self, rho0=float(hopper.rho0), g=float(hopper.g))

    def scales(self) -> tuple[float, float]:
        """`(L, V)`: the length and speed factors against `REFERENCE_HOPPER`, exactly
        `(1.0, 1.0)` for it (`froude_scales`)."""
        f = froude_scales(SimpleNamespace(m=REFERENCE_HOPPER[0], g=self.g, rho0=self.rho0))
        return f["length"], f["velocity"]

    def dimensionless(self) -> dict:
        """The constants in Froude units of the reference hopper: lengths over `rho0`,
        speeds over `sqrt(g rho0)`, `c` times `sqrt(g rho0)`; the same at every size."""
        _, g0, l0 = REFERENCE_HOPPER
        speed = math.sqrt(g0 * l0)
        return {"theta_avg": self.theta_avg, "v_max": self.v_max / speed,
                "cm": self.cm / l0, "ca": self.ca * speed, "cb": self.cb * speed,
                "co": self.co / speed, "cs": self.cs}

    def to_dict(self) -> dict:
        """The fields (part of a plan's cache key); `rho0` and `g` only when they are not
        the reference hopper's, so unscaled adjustments keep the key they always had."""
        out = dataclasses.asdict(self)
        if (self.rho0, self.g) == (REFERENCE_HOPPER[2], REFERENCE_HOPPER[1]):
            del out["rho0"], out["g"]
        return out

    def lead_coefficients(self) -> tuple[float, float, float]:
        """`(L, sin(theta_avg), V |v_max|)`: `lead(ydot)` is `L (ydot sin(theta_avg) /
        (V |v_max|))` (eq 37), the run-time controller's foot lead (`Templates.for_runs`)."""
        length, speed = self.scales()
        return length, math.sin(self.theta_avg), speed * abs(self.v_max)

    def lead(self, ydot):
        """`Y` of eq 37: how far ahead of the BHop foot the SLIP foot lands (m)."""
        return eq37_lead(ydot, self.lead_coefficients())

    def h(self, v):
        """`h(v)` of eq 35 (m), `v` in m/s of the hopper."""
        length, speed = self.scales()
        u = v / speed
        c = jnp.where(u < self.co, self.ca, self.cb)
        return length * (self.cm * (jnp.arctan(c * (u + self.co)) / jnp.pi - self.cs))


class Templates(eqx.Module):
    """A set of stride policy templates `[RE, RV, U]`, one row per template.

    Attributes:
        v_lo, v_hi: apex velocity range `RV` (m/s).
        e_lo, e_hi: apex energy range `RE` (J) relative to the virtual ground.
        dy_lo, dy_hi, th_lo, th_hi, k_lo, k_hi: control limits `U` (m, rad, -).
        seg_length: ground segment length `2l` (m); `None` in the run-time controller's
            templates, which carry it as `seg`.
        slip: the SLIP adjustments of section VII-A (`SlipAdjust`; `None` for BHop).
        lead: only in the run-time controller's templates (`for_runs`): the foot lead of
            eq 37 as traced coefficients (`SlipAdjust.lead_coefficients`), zero for BHop.
        seg: only in the run-time controller's templates: the segment length, traced.
    """

    v_lo: jnp.ndarray
    v_hi: jnp.ndarray
    e_lo: jnp.ndarray
    e_hi: jnp.ndarray
    dy_lo: jnp.ndarray
    dy_hi: jnp.ndarray
    th_lo: jnp.ndarray
    th_hi: jnp.ndarray
    k_lo: jnp.ndarray
    k_hi: jnp.ndarray
    seg_length: float | None = eqx.field(static=True, default=SEGMENT_LENGTH)
    slip: SlipAdjust | None = eqx.field(static=True, default=None)
    lead: jnp.ndarray | None = None
    seg: jnp.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.v_lo.shape[0])

    @property
    def segment(self):
        """The segment length `2l`: `seg_length`, or traced `seg` in the run-time
        templates."""
        return self.seg_length if self.seg is None else self.seg

    @property
    def half_length(self):
        return 0.5 * self.segment

    def row(self, i: int) -> Templates:
        """Template `i` alone (scalar leaves), for functions written for one template."""
        return Templates(*(getattr(self, f)[i] for f in _FIELDS), seg_length=self.seg_length,
                         slip=self.slip, lead=self.lead, seg=self.seg)

    def for_slip(self, adjust: SlipAdjust | None = None, hopper=None) -> Templates:
        """The same templates with the SLIP adjustments of section VII-A (eqs 35-37).

        Arguments:
            adjust: the adjustments (default: `SlipAdjust()` with `v_max` the largest
                template speed, in reference units: divided by `hopper`'s speed factor).
            hopper: scale them to this hopper (`SlipAdjust.for_hopper`); give it for
                templates of any hopper but the reference one (e.g. `scaled_templates`).
        """
        if adjust is None:
            speed = 1.0 if hopper is None else SlipAdjust().for_hopper(hopper).scales()[1]
            adjust = SlipAdjust(v_max=float(np.max(np.abs(np.asarray(
                jnp.concatenate([self.v_lo, self.v_hi]))))) / speed)
        if hopper is not None:
            adjust = adjust.for_hopper(hopper)
        return Templates(*(getattr(self, f) for f in _FIELDS), seg_length=self.seg_length,
                         slip=adjust)

    def for_runs(self) -> Templates:
        """These templates as the run-time controller reads them: the SLIP adjustments
        reduced to the foot lead of eq 37 (the domains of eq 36 and the recoveries use it),
        held as traced coefficients (`lead`), and the segment length traced (`seg`). BHop
        templates get a zero lead. Every plan of one template count, BHop or SLIP, of any
        hopper size and whatever its planning settings, then runs on one compiled
        controller."""
        if self.lead is not None:
            return self
        coeff = (1.0, 0.0, 1.0) if self.slip is None else self.slip.lead_coefficients()
        return Templates(*(getattr(self, f) for f in _FIELDS), seg_length=None,
                         lead=jnp.asarray(coeff, dtype=float),
                         seg=jnp.asarray(self.seg_length, dtype=float))

    def as_array(self) -> np.ndarray:
        return np.stack([np.asarray(getattr(self, f)) for f in _FIELDS], axis=1)

    def to_dict(self) -> dict:
        out = {"seg_length": self.seg_length,
               "templates": [dict(zip(_FIELDS, map(float, r))) for r in self.as_array()]}
        if self.slip is not None:
            out["slip"] = self.slip.to_dict()
        return out


def make_templates(rows, seg_length: float = SEGMENT_LENGTH) -> Templates:
    """Templates from rows `(v_lo, v_hi, e_lo, e_hi, dy_lo, dy_hi, th_lo, th_hi, k_lo, k_hi)`.

    Raises:
        InputError: empty set, a non-finite value, or a range whose low end exceeds its high
            end, or controls outside what the BHop model accepts.
    """
    arr = np.asarray(rows, dtype=float)
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] != len(_FIELDS):
        raise InputError(f"templates: expected a non-empty list of {len(_FIELDS)}-tuples "
                         f"{_FIELDS}")
    if not np.all(np.isfinite(arr)):
        i = int(np.argwhere(~np.isfinite(arr))[0, 0])
        raise InputError(f"templates[{i}]: all values must be finite")
    for a in range(0, len(_FIELDS), 2):
        bad = np.nonzero(arr[:, a] > arr[:, a + 1])[0]
        if bad.size:
            raise InputError(f"templates[{bad[0]}]: {_FIELDS[a]} > {_FIELDS[a + 1]}")
    if np.any(arr[:, 2] < 0):
        raise InputError(f"templates[{int(np.argmax(arr[:, 2] < 0))}]: e_lo must be >= 0")
    if np.any(arr[:, 8] <= -1):
        raise InputError(f"templates[{int(np.argmax(arr[:, 8] <= -1))}]: k_lo must be > -1")
    if np.any(np.abs(arr[:, 6:8]) > math.pi / 2 + 1e-12):
        raise InputError("templates: touchdown angles must lie in [-pi/2, pi/2]")
    if not (isinstance(seg_length, (int, float)) and 0 < seg_length < float("inf")):
        raise InputError(f"seg_length must be a positive length, got {seg_length!r}")
    return Templates(*(jnp.asarray(arr[:, c]) for c in range(len(_FIELDS))),
                     seg_length=float(seg_length))


def paper_templates(seg_length: float = SEGMENT_LENGTH) -> Templates:
    """The 20 BHop templates of eq 33 (section VI-A)."""
    velocities = [(-2.5, -1.0), (-1.0, 0.0), (0.0, 1.0), (1.0, 2.5)]
    energies = [(120, 160), (160, 240), (240, 400), (400, 640), (640, 1120)]
    rows = []
    for (v_lo, v_hi), (e_lo, e_hi) in itertools.product(velocities, energies):
        if v_hi <= 0:
            dy, th = (-0.25, 0.0), (-math.pi / 2, math.pi / 3)
        else:
            dy, th = (0.0, 0.25), (-math.pi / 3, math.pi / 2)
        rows.append((v_lo, v_hi, e_lo, e_hi, *dy, *th, 0.7, 1.4))
    return make_templates(rows, seg_length)


# --- size-independent (Froude-scaled) templates -------------------------------------------

def template_scales(hopper) -> dict:
    """Froude scale factors of `hopper` against `REFERENCE_HOPPER` (`froude_scales`)."""
    return froude_scales(hopper)


def dimensionless_templates(templates: Templates | None = None) -> np.ndarray:
    """Template rows in Froude units of the reference hopper.

    Velocities over `sqrt(g rho0)`, energies over `m g rho0`, `dy` over `rho0`; angles and
    `k` unchanged. Columns as `make_templates`, then the segment length over `rho0` as an
    eleventh column.
    """
    templates = paper_templates() if templates is None else templates
    m0, g0, l0 = REFERENCE_HOPPER
    arr = templates.as_array().copy()
    arr[:, 0:2] /= math.sqrt(g0 * l0)
    arr[:, 2:4] /= m0 * g0 * l0
    arr[:, 4:6] /= l0
    seg = np.full((arr.shape[0], 1), templates.seg_length / l0)
    return np.concatenate([arr, seg], axis=1)


def scaled_templates(hopper, extra_energy=(), base: Templates | None = None) -> Templates:
    """The paper's templates (or `base`) for a hopper of any size, by Froude scaling.

    Energy and velocity ranges, the horizontal-shift limits `dy` and the segment length are
    the reference values (written for `REFERENCE_HOPPER`, 80 kg, 9.81 m/s^2, 1 m) times the
    ratio of the two hoppers' scales (`template_scales`); angles and `k` are unchanged.
    SLIP adjustments of `base` are scaled to `hopper` (`SlipAdjust.for_hopper`). For the
    reference hopper every factor is exactly 1.0, so the result equals the base (default
    `paper_templates()`) bit for bit.

    Arguments:
        hopper: anything with `m`, `g`, `rho0`.
        extra_energy: additional dimensionless energy bands `(e_lo, e_hi)` in units of
            `m g rho0`, each added for every velocity band of the base set (with that
            band's control limits); e.g. for a robot that can jump higher, relative to its
            leg, than the paper's hopper (top band 1120 J = 1.43 m g rho0).
        base: templates to scale (default `paper_templates()`).

    Raises:
        InputError: a band that is not finite, not positive or empty.
    """
    base = paper_templates() if base is None else base
    f = template_scales(hopper)
    arr = base.as_array().copy()
    rows = [arr]
    if len(extra_energy):
        m0, g0, l0 = REFERENCE_HOPPER
        bands = np.asarray(extra_energy, dtype=float).reshape(-1, 2)
        if not np.all(np.isfinite(bands)) or np.any(bands[:, 0] < 0) or np.any(
                bands[:, 1] <= bands[:, 0]):
            raise InputError(f"extra_energy: bands must be finite with 0 <= lo < hi, got "
                             f"{bands.tolist()}")
        vel = np.unique(arr[:, [0, 1, 4, 5, 6, 7, 8, 9]], axis=0)
        for lo, hi in bands:
            extra = np.zeros((vel.shape[0], arr.shape[1]))
            extra[:, [0, 1, 4, 5, 6, 7, 8, 9]] = vel
            extra[:, 2], extra[:, 3] = lo * m0 * g0 * l0, hi * m0 * g0 * l0
            rows.append(extra)
    arr = np.concatenate(rows)
    arr[:, 0:2] *= f["velocity"]
    arr[:, 2:4] *= f["energy"]
    arr[:, 4:6] *= f["length"]
    out = make_templates(arr, base.seg_length * f["length"])
    return out if base.slip is None else out.for_slip(base.slip, hopper)
