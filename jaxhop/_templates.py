"""Stride policy templates (eq 4, eq 33): data, not code."""

from __future__ import annotations

import itertools
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._errors import InputError
from ._terrain import SEGMENT_LENGTH

_FIELDS = ("v_lo", "v_hi", "e_lo", "e_hi", "dy_lo", "dy_hi", "th_lo", "th_hi", "k_lo", "k_hi")


class Templates(eqx.Module):
    """A set of stride policy templates `[RE, RV, U]`, one row per template.

    Attributes:
        v_lo, v_hi: apex velocity range `RV` (m/s).
        e_lo, e_hi: apex energy range `RE` (J) relative to the virtual ground.
        dy_lo, dy_hi, th_lo, th_hi, k_lo, k_hi: control limits `U` (m, rad, -).
        seg_length: ground segment length `2l` (m).
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
    seg_length: float = eqx.field(static=True, default=SEGMENT_LENGTH)

    @property
    def n(self) -> int:
        return int(self.v_lo.shape[0])

    @property
    def half_length(self) -> float:
        return 0.5 * self.seg_length

    def row(self, i: int) -> Templates:
        """Template `i` alone (scalar leaves), for functions written for one template."""
        return Templates(*(getattr(self, f)[i] for f in _FIELDS), seg_length=self.seg_length)

    def as_array(self) -> np.ndarray:
        return np.stack([np.asarray(getattr(self, f)) for f in _FIELDS], axis=1)

    def to_dict(self) -> dict:
        return {"seg_length": self.seg_length,
                "templates": [dict(zip(_FIELDS, map(float, r))) for r in self.as_array()]}


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
