"""The SLIP adjustments (eqs 35-37) at any hopper size, by Froude similarity."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxhop import Hopper, builtin_terrain, paper_templates
from jaxhop._core.terrain import make_terrain
from jaxhop._models.slip.stride import slip_strides
from jaxhop._planning.cache import plan_key
from jaxhop._planning.regions import foot_lead, slip_shift_limits
from jaxhop._planning.templates import SlipAdjust, scaled_templates
from jaxhop.parkour import leg_hopper, leg_templates

REFERENCE = Hopper()
LEG = leg_hopper()  # 1 kg, g = 8.0665, rho0 = 0.19
SMALL = Hopper(m=5.0, g=9.81, rho0=0.3)
LARGE = Hopper(m=5.0, g=3.71, rho0=2.0)


def _eq35_37_as_fitted(v, ydot):
    # The formulas for the 1 m hopper, written out with the default constants.
    c = jnp.where(v < -1.149, 2.018, 2.018)
    h = 0.659 * (jnp.arctan(c * (v + -1.149)) / jnp.pi - 0.2252)
    return h, ydot * math.sin(0.2) / abs(2.5)


def test_the_reference_hopper_keeps_its_adjustments_bit_for_bit():
    v = jnp.linspace(-3.0, 3.0, 1201)
    want_h, want_y = _eq35_37_as_fitted(v, v)
    for adj in (SlipAdjust(), SlipAdjust().for_hopper(REFERENCE),
                SlipAdjust().for_hopper(LEG).for_hopper(REFERENCE),
                paper_templates().for_slip(hopper=REFERENCE).slip):
        assert adj.scales() == (1.0, 1.0)
        np.testing.assert_array_equal(adj.h(v), want_h)
        np.testing.assert_array_equal(adj.lead(v), want_y)
        np.testing.assert_array_equal(jax.jit(adj.h)(v), jax.jit(
            lambda x: _eq35_37_as_fitted(x, x)[0])(v))
    # Same templates, same limits row by row, same cache key as the unscaled ones.
    a, b = paper_templates().for_slip(), paper_templates().for_slip(hopper=REFERENCE)
    assert a.slip == b.slip and a.to_dict() == b.to_dict()
    assert set(a.to_dict()["slip"]) == {"theta_avg", "v_max", "cm", "ca", "cb", "co", "cs",
                                        "reversal", "keep_direction",
                                        "direction_slack"}
    for t in range(a.n):
        for ydot in (-1.7, -0.2, 0.0, 0.4, 2.1):
            y = jnp.asarray(ydot)
            assert slip_shift_limits(y, a.row(t)) == slip_shift_limits(y, b.row(t))
            assert foot_lead(y, a.row(t)) == foot_lead(y, b.row(t))
    terrain = builtin_terrain("flat")
    assert plan_key(terrain, terrain.goal, a, REFERENCE) == plan_key(
        terrain, terrain.goal, scaled_templates(REFERENCE, base=a), REFERENCE)


@pytest.mark.parametrize("hopper", [LEG, SMALL, LARGE], ids=["leg", "small", "large"])
def test_scaled_adjustments_are_the_reference_ones_in_froude_units(hopper):
    adj = SlipAdjust().for_hopper(hopper)
    length, speed = adj.scales()
    assert length == pytest.approx(hopper.rho0)
    assert speed == pytest.approx(math.sqrt(hopper.g * hopper.rho0 / 9.81))
    u = np.linspace(-2.5, 2.5, 501)  # reference speeds (m/s)
    ref = SlipAdjust()
    np.testing.assert_allclose(adj.h(jnp.asarray(u * speed)) / length, ref.h(jnp.asarray(u)),
                               rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(adj.lead(u * speed), hopper.rho0 * u * math.sin(0.2) / 2.5,
                               rtol=1e-12, atol=1e-15)
    # Truly dimensionless: h / rho0 against ydot / sqrt(g rho0).
    d = ref.dimensionless()
    w = u * speed / math.sqrt(hopper.g * hopper.rho0)
    c = np.where(w < d["co"], d["ca"], d["cb"])
    np.testing.assert_allclose(adj.h(jnp.asarray(u * speed)) / hopper.rho0,
                               d["cm"] * (np.arctan(c * (w + d["co"])) / np.pi - d["cs"]),
                               rtol=1e-12, atol=1e-15)
    # The mass does not enter.
    heavier = Hopper(m=40.0 * float(hopper.m), g=hopper.g, rho0=hopper.rho0)
    assert SlipAdjust().for_hopper(heavier) == adj


def test_leg_templates_carry_the_leg_scaled_adjustments_into_the_cache_key():
    leg = leg_templates(LEG)
    slip = leg.for_slip(hopper=LEG)
    assert slip.slip.rho0 == LEG.rho0 and slip.slip.g == LEG.g
    assert slip.slip.v_max == pytest.approx(2.5)  # the reference units' largest speed
    assert scaled_templates(LEG, base=paper_templates().for_slip()).slip == SlipAdjust(
        rho0=LEG.rho0, g=LEG.g)
    d = slip.to_dict()["slip"]
    assert (d["rho0"], d["g"]) == (LEG.rho0, LEG.g)
    terrain = builtin_terrain("flat")
    keys = {plan_key(terrain, terrain.goal, t, LEG)
            for t in (leg, leg.for_slip(SlipAdjust(v_max=2.5)), slip)}
    assert len(keys) == 3


def _shift_band_fraction(hopper, n=3000, seed=11):
    """Fresh SLIP strides of `hopper` over flat ground, sampled as
    `test_fitted_eq35_band_holds_most_slip_strides` samples the 1 m hopper's, in Froude
    units (speeds times V, energies times m g rho0 / (80 kg 9.81 m/s^2 1 m)).

    Returns:
        `(kept, dy / rho0, fraction in the scaled band, fraction in the unscaled band)`.
    """
    speed = math.sqrt(hopper.g * hopper.rho0 / 9.81)
    energy = hopper.m * hopper.g * hopper.rho0 / (80.0 * 9.81)
    mg = hopper.m * hopper.g
    rng = np.random.default_rng(seed)
    ydot = speed * rng.uniform(-2.5, 2.5, n)
    zr = (energy * rng.uniform(120.0, 1120.0, n) - 0.5 * hopper.m * ydot**2) / mg
    keep = zr > 0.01 * hopper.rho0
    ydot, zr = ydot[keep], zr[keep]
    k = ydot.size
    kc = rng.uniform(10.0, 60.0, k) * mg / hopper.rho0
    u = np.stack([rng.uniform(-np.pi / 3, np.pi / 3, k), kc,
                  kc * np.exp(rng.uniform(np.log(0.5), np.log(2.0), k))], 1)
    apex = np.stack([np.zeros(k), zr + hopper.rho0, ydot], 1)
    flat = make_terrain([(-50.0 * hopper.rho0, 50.0 * hopper.rho0, 0.0)])
    nxt, code, foot = slip_strides(apex, u, flat, hopper)
    zr1 = nxt[:, 1] - hopper.rho0
    e1 = 0.5 * hopper.m * nxt[:, 2] ** 2 + mg * zr1
    ok = ((code == 0) & (zr1 > 0) & (np.abs(nxt[:, 2]) <= 2.5 * speed) & (e1 >= 120 * energy)
          & (e1 <= 1120 * energy))
    dy = nxt[ok, 0] - nxt[ok, 2] * np.sqrt(2 * zr1[ok] / hopper.g) - foot[ok, 0]
    v = jnp.asarray(0.5 * (ydot[ok] + nxt[ok, 2]))
    held = []
    for adj in (SlipAdjust().for_hopper(hopper), SlipAdjust()):
        held.append(float(np.mean((dy >= np.asarray(adj.h(v)))
                                  & (dy <= -np.asarray(adj.h(-v))))))
    return ok, dy / hopper.rho0, held[0], held[1]


def test_scaled_eq35_band_holds_as_many_fresh_strides_at_every_size():
    # The band fitted for the 1 m hopper holds 65-92 % of fresh strides there (the stated
    # fraction of `test_fitted_eq35_band_holds_most_slip_strides`); scaled, it holds the
    # same strides of the leg, a 0.3 m hopper and a 2 m hopper on a smaller planet. The
    # unscaled band does not: it holds every stride of the small hoppers (it is wider than
    # they can shift) and too few of the large one's.
    ok0, dy0, frac0, _ = _shift_band_fraction(REFERENCE)
    assert ok0.sum() > 200 and 0.65 < frac0 < 0.92
    for hopper in (LEG, SMALL, LARGE):
        ok, dy, frac, unscaled = _shift_band_fraction(hopper)
        assert np.array_equal(ok, ok0)
        np.testing.assert_allclose(dy, dy0, atol=1e-6)  # Froude similarity of the strides
        assert 0.65 < frac < 0.92 and abs(frac - frac0) <= 0.01
        assert not 0.65 < unscaled < 0.92
