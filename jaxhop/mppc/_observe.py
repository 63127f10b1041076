"""An observer for MPPC under disturbances: wind and landing-error room from past landings.

A jump planned for wind `a_used` to land at `x_plan` after the flight time `t`, and
measured (by the contact sensor) at `x_meas`, gives the wind sample
`a = a_used + 2 (x_meas - x_plan) / t^2`: in a constant horizontal acceleration the
landing moves by `a t^2 / 2` (docs/mppc.md, "Disturbances"). The estimate is the mean of
the `n` samples seen, which also averages the landing and sensing noise, and it is used
only where it stands out of that noise: `|mean| > 2 SE` with
`SE = sqrt((s^2 + s0^2) / n)`, `s` the samples' standard deviation and `s0`
(`wind_spread`) a prior spread that makes a single sample decide (otherwise the wind is
taken as 0). What the wind in use does not explain, `x_meas - x_plan - (a - a_used) t^2 /
2` for every landing seen, measures the landing and sensing error; the room the planner
keeps around edges, restricted areas and blocks is `gain (n + 1) / n` times the largest
such residual (for `n` uniform errors, `(n + 1) / n` times their largest magnitude
estimates the bound without bias), at least `room_min`, at most `room_max`; until
`n_first` landings have been seen, at least `room_first` (a bound from one or two
landings is unreliable).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Observer:
    """Wind estimate and landing room from the landings seen so far.

    - `room_first`, `n_first`: the least room (m) until `n_first` landings have been seen.
    - `gain`: room per metre of the bias-corrected largest unexplained residual.
    - `room_min`, `room_max`: bounds on the room once landings have been seen (m).
    - `wind_spread`: prior spread `s0` of one wind sample (m/s^2; a 1 cm landing error
      over a 0.5 s flight is 0.08).
    - `wind_max`: bound on the wind estimate's magnitude (m/s^2).
    """

    room_first: float = 0.015
    n_first: int = 3
    gain: float = 1.0
    room_min: float = 0.0
    room_max: float = 0.03
    wind_spread: float = 0.04
    wind_max: float = 1.0
    _seen: list = field(default_factory=list)  # (residual, t, wind used) per landing

    def update(self, x_plan: float, x_meas: float, t: float, wind_used: float) -> None:
        """Record a landing: planned at `x_plan` for wind `wind_used`, flight time `t`,
        measured at `x_meas`."""
        if not (t > 0 and np.isfinite(x_meas - x_plan)):
            raise ValueError("Observer.update: need a positive flight time and finite points")
        self._seen.append((float(x_meas - x_plan), float(t), float(wind_used)))

    @property
    def n(self) -> int:
        """Landings seen."""
        return len(self._seen)

    def samples(self) -> np.ndarray:
        """One wind sample per landing seen (m/s^2): `a_used + 2 (x_meas - x_plan) / t^2`."""
        if not self._seen:
            return np.zeros(0)
        r, t, a = (np.array(c) for c in zip(*self._seen))
        return a + 2.0 * r / t**2

    @property
    def wind(self) -> float:
        """The wind in use (m/s^2): the samples' mean where it stands out of their noise
        (`|mean| > 2 SE`), else 0; 0 before any landing."""
        a = self.samples()
        if not a.size:
            return 0.0
        mean = float(np.mean(a))
        spread = float(np.std(a, ddof=1)) if a.size > 1 else 0.0
        se = np.sqrt((spread**2 + self.wind_spread**2) / a.size)
        if abs(mean) <= 2.0 * se:
            return 0.0
        return float(np.clip(mean, -self.wind_max, self.wind_max))

    def residuals(self) -> np.ndarray:
        """Landing residuals that the current wind estimate does not explain (m)."""
        if not self._seen:
            return np.zeros(0)
        r, t, a = (np.array(c) for c in zip(*self._seen))
        return r - (self.wind - a) * t**2 / 2

    @property
    def room(self) -> float:
        """The extra horizontal room to keep (m)."""
        n = len(self._seen)
        least = self.room_first if n < self.n_first else self.room_min
        if not n:
            return float(np.clip(least, 0.0, self.room_max))
        bound = self.gain * (n + 1) / n * float(np.max(np.abs(self.residuals())))
        return float(np.clip(max(bound, least), 0.0, self.room_max))
