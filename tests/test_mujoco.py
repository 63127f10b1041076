"""The MuJoCo hopper against jaxhop's SLIP: one simulator is the other's reference."""

import numpy as np
import pytest

pytest.importorskip("mujoco")

from jaxhop import Hopper, make_terrain  # noqa: E402
from jaxhop._result import Result  # noqa: E402
from jaxhop._slip import slip_strides  # noqa: E402
from jaxhop.mujoco import IDEAL, Mechanics, Simulator, hopper_xml  # noqa: E402

HOPPER = Hopper()
FLAT = make_terrain([(-20.0, 20.0, 0.0)], name="flat")


def _admissible_strides(n, seed):
    """`n` random strides on flat ground that jaxhop's SLIP completes to an apex at least
    5 cm above a vertical leg: `(apex, u, next_apex)`."""
    rng = np.random.default_rng(seed)
    m = 4 * n
    weight = HOPPER.m * HOPPER.g / HOPPER.rho0
    apex = np.stack([rng.uniform(-1.0, 1.0, m), rng.uniform(1.1, 1.6, m),
                     rng.uniform(-0.5, 2.0, m)], axis=1)
    kc = rng.uniform(10.0, 40.0, m) * weight
    u = np.stack([rng.uniform(-0.1, 0.45, m), kc, kc * rng.uniform(0.7, 1.5, m)], axis=1)
    nxt, code, _ = slip_strides(apex, u, FLAT, HOPPER)
    keep = np.nonzero((code == 0) & (nxt[:, 1] > 1.05))[0][:n]
    assert keep.size == n
    return apex[keep], u[keep], nxt[keep]


@pytest.mark.slow
def test_ideal_mujoco_stride_agrees_with_slip_stride():
    apex, u, expect = _admissible_strides(50, seed=21)
    sim = Simulator(HOPPER, FLAT, IDEAL)
    got = []
    for a, c in zip(apex, u):
        sim.reset(a, c[0])
        s = sim.stride(c)
        assert s.code == Result.SUCCESS
        got.append(s.apex)
    err = np.abs(np.asarray(got) - expect)
    assert np.max(err[:, :2]) < 5e-3, np.max(err[:, :2], axis=0)
    assert np.max(err[:, 2]) < 0.02, np.max(err[:, 2])


def test_model_masses_and_geometry():
    mech = Mechanics()
    sim = Simulator(HOPPER, FLAT, mech)
    total = sim.model.body_subtreemass[sim.model.body("body").id]
    assert total == pytest.approx(HOPPER.m * (1 + mech.leg_mass + mech.foot_mass), rel=1e-9)
    sim.reset([0.0, 1.5, 0.0], th=0.3)
    foot = sim.foot_point()
    # the foot's centre is rho0 - r from the hip along the leg, 0.3 rad ahead
    r = mech.foot_radius * HOPPER.rho0
    assert foot[0] == pytest.approx((HOPPER.rho0 - r) * np.sin(0.3), abs=1e-12)
    assert foot[1] == pytest.approx(1.5 - (HOPPER.rho0 - r) * np.cos(0.3) - r, abs=1e-12)
    assert hopper_xml(HOPPER, FLAT, mech).count('type="box"') == 1
