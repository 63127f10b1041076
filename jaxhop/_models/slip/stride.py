"""Spring-loaded inverted pendulum (SLIP): stance, stride and apex return map (section IV-A).

Stance is integrated in polar coordinates about the foot (eq 10), with the COM at
`foot + rho (-sin th, cos th)`; `th > 0` puts the foot ahead of the COM. The spring constant
is `kc` while compressing and `kd` while decompressing, so stance is two diffrax solves:
touchdown -> bottom (`rho' = 0`, up-crossing) and bottom -> liftoff (`rho = rho0`,
up-crossing: `direction=True`, otherwise the event fires at the touchdown state itself).

Every function handles one sample; batch with `jax.vmap`. Failures are result codes
(`flight.py`): a solve that does not finish is `SOLVER`; a stance that cannot complete
(the COM reaching the foot's ground level, a leg that is not loaded at touchdown, no
liftoff, a leg compressed below `COLLAPSED * rho0`, a liftoff that does not rise) is
`COLLISION`.
"""

import functools
from typing import NamedTuple

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..._core.batching import chunked_map
from ..._core.params import Hopper
from ..._core.programs import jit
from ..._core.terrain import Terrain
from ..bhop import safe_sqrt
from ..flight import COLLISION, OK, SOLVER, flight_crossings, flight_position, touchdown

# Tolerances of the simulated stride; the deadbeat searches use looser ones (see there).
RTOL = 1e-10
ATOL = 1e-10
# Longest phase (s): far beyond any stance with kc rho0 / (m g) >= 10 (half period < 0.33 s).
PHASE_T_MAX = 5.0
MAX_STEPS = 4096
# A leg shorter than this fraction of rho0 counts as collapsed (a body-ground collision).
COLLAPSED = 0.25


class Tolerances(eqx.Module):
    """How the stance phases are integrated (all static).

    `steps = 0`: adaptive Tsit5 steps at `rtol`, `atol`, the phase's end located by
    diffrax's event (`adjoint` for reverse mode). `steps > 0`: a fixed-shape phase
    (`fixed_phase`) of that many equal Tsit5 steps; `rtol`, `atol` and `adjoint` unused.
    `fixed_loops`: the searches around the strides (Gauss-Newton turns, table starts,
    candidates) run a fixed number of turns with finished lanes frozen
    (`jaxhop._core.batching.bounded_while`): with fixed-shape strides, no data-dependent
    loop is left (accelerators).
    """

    rtol: float = eqx.field(static=True, default=RTOL)
    atol: float = eqx.field(static=True, default=ATOL)
    adjoint: diffrax.AbstractAdjoint = eqx.field(
        static=True, default_factory=diffrax.RecursiveCheckpointAdjoint)
    steps: int = eqx.field(static=True, default=0)
    fixed_loops: bool = eqx.field(static=True, default=False)

    @property
    def accuracy(self) -> float:
        """The apex error these strides stay within: the larger tolerance, or with fixed
        steps (at least 10) 1e-5 (`docs/slip.md`, "Fixed-shape trial strides")."""
        return 1e-5 if self.steps else max(self.rtol, self.atol)

    def forward(self):
        """These settings with forward-mode differentiation through the adaptive solves."""
        return Tolerances(self.rtol, self.atol, diffrax.ForwardMode(), self.steps,
                          self.fixed_loops)


STRIDE_TOL = Tolerances()


class Stance(NamedTuple):
    """Result of one stance. Positions are relative to the foot.

    `code`: `OK` or a failure; `p_lo`, `v_lo`: COM position and velocity at liftoff;
    `rho_b`: leg length at the bottom; `z_min`: lowest COM height among touchdown, bottom
    and liftoff (for the clearance check).
    """

    code: jnp.ndarray
    p_lo: jnp.ndarray
    v_lo: jnp.ndarray
    rho_b: jnp.ndarray
    z_min: jnp.ndarray


def _field(t, x, args):
    rho, th, rhod, thd = x
    k, hopper = args
    rhodd = rho * thd**2 - (k / hopper.m) * (rho - hopper.rho0) - hopper.g * jnp.cos(th)
    thdd = (-2.0 * rhod * thd + hopper.g * jnp.sin(th)) / rho
    return jnp.stack([rhod, thd, rhodd, thdd])


def _fallen(t, y, args, **kwargs):
    # The body meets the ground: the COM at the foot's level, or the leg collapsed below
    # `COLLAPSED * rho0` (which also keeps the solver away from the singularity at rho = 0).
    return jnp.minimum(y[0] * jnp.cos(y[1]), y[0] - COLLAPSED * args[1].rho0)


def _bottom(t, y, args, **kwargs):
    return y[2]


def _liftoff(t, y, args, **kwargs):
    return y[0] - args[1].rho0


def _phase_end(cond):
    """A stance phase's end: `max(cond, -fallen)` up-crossing 0 (see `_phase`)."""
    def end(t, y, args, **kwargs):
        return jnp.maximum(cond(t, y, args), -_fallen(t, y, args))

    return end


def _adaptive_phase(x0, k, hopper: Hopper, end, tol: Tolerances, saveat):
    """Eq 10 from `x0` in adaptive Tsit5 steps at `tol` until `end` up-crosses 0."""
    event = diffrax.Event(cond_fn=end, root_finder=optx.Newton(rtol=1e-13, atol=1e-13),
                          direction=True)
    return diffrax.diffeqsolve(
        diffrax.ODETerm(_field), diffrax.Tsit5(), 0.0, PHASE_T_MAX, None, x0,
        args=(k, hopper), saveat=saveat,
        stepsize_controller=diffrax.PIDController(rtol=tol.rtol, atol=tol.atol),
        event=event, max_steps=MAX_STEPS, throw=False, adjoint=tol.adjoint,
    )


# Jitted so that every stance phase of one kind (compression or decompression, at one
# tolerance) is traced once per process: a SLIP decision integrates dozens of them, and each
# trace of a diffrax solve with its event takes about a second of Python. Inside a jaxhop
# program the call is inlined and compiled with the program's options.
@functools.partial(jax.jit, static_argnames=("cond", "tol"))
def _phase(x0, k, hopper: Hopper, cond, tol: Tolerances):
    """Integrate eq 10 from `x0` until `cond` up-crosses 0 (or the COM falls).

    The two ends are one event, `max(cond, -fallen)` up-crossing 0 (the first of the two;
    a single event function costs a third less per phase than two), and the branch that
    is 0 at the end tells which one fired.

    Returns:
        `(x_end, code)`: `OK` when `cond` fired, `COLLISION` when the COM fell or the phase
        never ended, `SOLVER` when diffrax failed.
    """
    end = _phase_end(cond)
    if tol.steps:
        return fixed_phase(x0, k, hopper, end, cond, tol.steps)

    sol = _adaptive_phase(x0, k, hopper, end, tol, diffrax.SaveAt(t1=True))
    x_end = sol.ys[-1]
    fell = -_fallen(0.0, x_end, (k, hopper)) >= cond(0.0, x_end, (k, hopper))
    fired = sol.event_mask
    ok_solve = diffrax.is_okay(sol.result)
    code = jnp.where(~ok_solve | ~jnp.all(jnp.isfinite(x_end)), SOLVER,
                     jnp.where(fired & ~fell, OK, COLLISION))
    return x_end, code


# The fixed-shape phase spans this multiple of its predicted duration (`phase_time`), at
# most `SPAN_MAX` half periods of the bare spring, pi sqrt(m / k).
SPAN = 1.5
SPAN_MAX = 1.25
# Newton turns that locate the phase's end on the step's dense output.
EVENT_NEWTON = 6
# The Runge-Kutta stages of a fixed-shape step run in equinox's bounded loop (a scan of
# conditional turns): forward-mode derivatives go through it, as through "lax"'s while loop,
# and it leaves no data-dependent loop in the step.
STAGES = "bounded"


def phase_time(x0, k, hopper: Hopper, to_bottom: bool):
    """The duration of a stance phase from `x0` (polar) on the radial motion linearised
    about `rho0`: a spring of stiffness `k / m + 3 th'^2` (the centrifugal term with the
    angular momentum kept) about a centre that gravity and that term shift by
    `a / w^2`, `a = g cos th - rho0 th'^2`. `to_bottom`: until `rho' = 0` (compression),
    else until `rho = rho0` (decompression from rest at the bottom); a decompression that
    would not reach `rho0` gets half a period."""
    rho, th, rhod, thd = x0
    w2 = k / hopper.m + 3.0 * thd**2
    w = safe_sqrt(w2)
    a = hopper.g * jnp.cos(th) - hopper.rho0 * thd**2
    u0 = rho - hopper.rho0 + a / w2
    if to_bottom:
        return (jnp.pi - jnp.arctan2(-rhod / w, u0)) / w
    ratio = (a / w2) / jnp.where(u0 != 0, u0, -1.0)
    return jnp.where(jnp.abs(ratio) < 1, jnp.arccos(jnp.clip(ratio, -1, 1)), jnp.pi) / w


def fixed_phase(x0, k, hopper: Hopper, end, cond, steps: int):
    """`_phase` with a fixed shape: `steps` equal Tsit5 steps over `SPAN` times the
    phase's predicted duration (`phase_time`; a `lax.scan`, no data-dependent loop), then
    `EVENT_NEWTON` Newton turns on the dense output of the step in which `end` first
    up-crosses 0. Every lane does the same work, and forward-mode derivatives go through
    it as through any arithmetic. Returns `(x_end, code)` as `_phase` does; a phase that
    does not end inside the span is `COLLISION`, as one that never ends."""
    term, solver, args = diffrax.ODETerm(_field), diffrax.Tsit5(scan_kind=STAGES), (k, hopper)
    span = jnp.minimum(SPAN * phase_time(x0, k, hopper, cond is _bottom),
                       SPAN_MAX * jnp.pi * safe_sqrt(hopper.m / k))
    dt = jnp.minimum(span, PHASE_T_MAX) / steps

    def turn(carry, i):
        y, state, e, found, crossing = carry
        t0 = i * dt
        y1, _, dense, state1, _ = solver.step(term, t0, t0 + dt, y, args, state, False)
        e1 = end(t0 + dt, y1, args)
        now = ~found & (e < 0) & (e1 >= 0)
        crossing = jax.tree.map(lambda new, old: jnp.where(now, new, old),
                                (t0, e, e1, dense), crossing)
        # After the end the state stays put (a lane past a fall must not reach rho = 0).
        stop = found | now
        y, state, e = jax.tree.map(lambda old, new: jnp.where(stop, old, new),
                                   (y, state, e), (y1, state1, e1))
        return (y, state, e, stop, crossing), None

    state0 = solver.init(term, 0.0, dt, x0, args)
    # The dense output's shapes, without a step of its own.
    dense0 = jax.eval_shape(lambda: solver.step(term, 0.0, dt, x0, args, state0, False))[2]
    e0 = end(0.0, x0, args)
    crossing0 = (jnp.zeros_like(dt), e0, e0,
                 jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), dense0))
    (_, _, _, found, (t0, e_a, e_b, dense)), _ = jax.lax.scan(
        turn, (x0, state0, e0, jnp.asarray(False), crossing0), jnp.arange(steps))
    interp = solver.interpolation_cls(t0=t0, t1=t0 + dt, **dense)

    def residual(t):
        return end(t, interp.evaluate(t), args)

    # Start from the secant of the step's two ends, then Newton within the step.
    t = t0 + dt * jnp.clip(-e_a / jnp.where(e_b != e_a, e_b - e_a, 1.0), 0.0, 1.0)
    for _ in range(EVENT_NEWTON):
        r, slope = jax.jvp(residual, (t,), (jnp.ones_like(t),))
        t = jnp.clip(t - r / jnp.where(slope != 0, slope, 1.0), t0, t0 + dt)
    x_end = interp.evaluate(t)
    fell = -_fallen(0.0, x_end, args) >= cond(0.0, x_end, args)
    code = jnp.where(~jnp.all(jnp.isfinite(x_end)), SOLVER,
                     jnp.where(found & ~fell, OK, COLLISION))
    return x_end, code


def polar_state(th, v):
    """Polar state `(rho0 implied)` rates from a COM velocity `v` with the leg at angle `th`."""
    e_r = jnp.stack([-jnp.sin(th), jnp.cos(th)])
    e_th = jnp.stack([-jnp.cos(th), -jnp.sin(th)])
    return jnp.dot(v, e_r), jnp.dot(v, e_th)


def cartesian(x):
    rho, th, rhod, thd = x
    e_r = jnp.stack([-jnp.sin(th), jnp.cos(th)])
    e_th = jnp.stack([-jnp.cos(th), -jnp.sin(th)])
    return rho * e_r, rhod * e_r + rho * thd * e_th


def compress(th_td, v_td, kc, hopper: Hopper, tol: Tolerances = STRIDE_TOL):
    """Compression from touchdown (leg at `th_td`, COM velocity `v_td`) to the bottom.

    Returns:
        `(x_b, code)`: polar state `(rho, th, rho', th')` at the bottom. A leg whose length
        would grow at touchdown (`rho' >= 0`) is never loaded: `COLLISION`.
    """
    x0, loaded = _touchdown_state(th_td, v_td, hopper)
    x_b, code = _phase(x0, kc, hopper, _bottom, tol)
    return x_b, jnp.where(loaded, code, COLLISION)


def _touchdown_state(th_td, v_td, hopper: Hopper):
    """The polar state at touchdown and whether the leg is loaded (`rho' < 0`). An unloaded
    leg gets a harmless dummy state, so that its solve stays uniform under vmap."""
    rhod, vth = polar_state(th_td, v_td)
    loaded = rhod < 0
    x0 = jnp.stack([hopper.rho0, th_td, jnp.where(loaded, rhod, -1.0),
                    jnp.where(loaded, vth / hopper.rho0, 0.0)])
    return x0, loaded


def sampled_stance(th_td, v_td, kc, kd, hopper: Hopper, n: int, tol: Tolerances = STRIDE_TOL):
    """Both stance phases as `stance` integrates them, each sampled at `n` instants evenly
    spaced in time from its start to its end (dense output; for drawing).

    Returns:
        `(states, loaded)`: `(2 n, 4)` polar states, compression then decompression, and
        whether the leg is loaded at touchdown (if not, the states are a dummy's).
    """
    x0, loaded = _touchdown_state(th_td, v_td, hopper)

    def sampled(x, k, cond):
        saveat = diffrax.SaveAt(t1=True, dense=True)
        sol = _adaptive_phase(x, k, hopper, _phase_end(cond), tol, saveat)
        return jax.vmap(sol.evaluate)(jnp.linspace(0.0, 1.0, n) * sol.ts[-1])

    comp = sampled(x0, kc, _bottom)
    return jnp.concatenate([comp, sampled(comp[-1], kd, _liftoff)]), loaded


def decompress(x_b, kd, hopper: Hopper, tol: Tolerances = STRIDE_TOL):
    """Decompression from the bottom state `x_b` to liftoff (`rho = rho0`, `rho' > 0`)."""
    return _phase(x_b, kd, hopper, _liftoff, tol)


# Limits of kd / kc (eq 14; `docs/slip.md`, "Deadbeat").
KD_RATIO = (0.5, 2.0)


def bottom_kd(x_b, h, kc, energy, hopper: Hopper):
    """Eq 12 at the bottom of the stance: the `kd` that lifts off with apex energy `energy`.

    `energy = m g z + m ydot^2 / 2` of the target apex (world frame). The mechanical energy
    with the compression spring, measured at the bottom (`x_b`, foot at height `h`), is
    what the stance carries; switching to `kd` adds `(kd - kc) (rho0 - rho_b)^2 / 2`.
    Clipped to `KD_RATIO`.
    """
    p, v = cartesian(x_b)
    m, g = hopper.m, hopper.g
    now = m * g * (h + p[1]) + 0.5 * m * jnp.dot(v, v) + 0.5 * kc * (hopper.rho0 - x_b[0]) ** 2
    kd = kc + 2.0 * (energy - now) / (x_b[0] - hopper.rho0) ** 2
    return jnp.clip(kd, KD_RATIO[0] * kc, KD_RATIO[1] * kc)


def stance(th_td, v_td, kc, kd, hopper: Hopper, tol: Tolerances = STRIDE_TOL, energy=None,
           h=0.0) -> Stance:
    """Both stance phases of eq 10, from touchdown to liftoff, relative to the foot.

    With a finite `energy`, `kd` is replaced by `bottom_kd` (foot at height `h`).
    """
    x_b, code_c = compress(th_td, v_td, kc, hopper, tol)
    if energy is not None:
        kd = jnp.where(jnp.isfinite(energy), bottom_kd(x_b, h, kc, energy, hopper), kd)
    x_lo, code_d = decompress(x_b, kd, hopper, tol)
    code = jnp.where(code_c != OK, code_c, code_d)
    p_lo, v_lo = cartesian(x_lo)
    return Stance(code, p_lo, v_lo, x_b[0], lowest_com(th_td, x_b, p_lo, hopper))


def lowest_com(th_td, x_b, p_lo, hopper: Hopper):
    """The COM height over the foot that the clearance check takes as the stance's lowest:
    the lowest of touchdown (leg at `th_td`), bottom (`x_b`) and liftoff (`p_lo`)."""
    return jnp.minimum(jnp.minimum(hopper.rho0 * jnp.cos(th_td), x_b[0] * jnp.cos(x_b[1])),
                       p_lo[1])


def ascent(p_lo, v_lo, hopper: Hopper, wind=0.0):
    """Ballistic rise from liftoff at world position `p_lo` to the apex."""
    t_up = jnp.maximum(v_lo[1], 0.0) / hopper.g
    return jnp.stack([p_lo[0] + v_lo[0] * t_up + 0.5 * wind * t_up**2,
                      p_lo[1] + 0.5 * v_lo[1] * t_up,
                      v_lo[0] + wind * t_up])


def flat_touchdown(apex, th_td, h, hopper: Hopper, wind=None):
    """Descent to a flat foothold at `h` with the foot at `COM + rho0 (sin th, -cos th)`.

    `wind`: a horizontal acceleration in the descent (`None`: none, the windless expressions
    as they are).

    Returns:
        `(y_foot, v_td, reached)`; `reached` is False when the foot starts below `h`.
    """
    y, z, ydot = apex
    drop = z - h - hopper.rho0 * jnp.cos(th_td)
    t_d = safe_sqrt(2.0 * drop / hopper.g)
    if wind is None:
        y_foot = y + ydot * t_d + hopper.rho0 * jnp.sin(th_td)
        return y_foot, jnp.stack([ydot, -hopper.g * t_d]), drop >= 0
    y_foot = y + ydot * t_d + 0.5 * wind * t_d**2 + hopper.rho0 * jnp.sin(th_td)
    return y_foot, jnp.stack([ydot + wind * t_d, -hopper.g * t_d]), drop >= 0


def slip_apex_map(apex, u, h, hopper: Hopper, tol: Tolerances = STRIDE_TOL, wind=None,
                  energy=None):
    """SLIP apex return map over flat ground at height `h` (no walls).

    Arguments:
        apex: `(y, z, ydot)`, world frame.
        u: `(th_td, kc, kd)`.
        h: foothold height.
        wind: horizontal acceleration in both flight phases (`None`: none).
        energy: as in `slip_stride`: a finite target apex energy replaces `kd` by
            `bottom_kd` at the bottom of the stance.

    Returns:
        `(next_apex, code)`.
    """
    th, kc, kd = u
    y_foot, v_td, reached = flat_touchdown(apex, th, h, hopper, wind)
    st = stance(th, v_td, kc, kd, hopper, tol, energy, h)
    nxt = ascent(st.p_lo + jnp.stack([y_foot, h]), st.v_lo, hopper,
                 0.0 if wind is None else wind)
    code = jnp.where(~reached, COLLISION, jnp.where(st.code != OK, st.code,
                                                    jnp.where(st.v_lo[1] > 0, OK, COLLISION)))
    return nxt, code


def _rise_clear(p_lo, v_lo, terrain: Terrain, hopper: Hopper, wind):
    """Whether the COM rising ballistically from liftoff to apex crosses no wall."""
    t_up = jnp.maximum(v_lo[1], 0.0) / hopper.g

    def wall_hit(w):
        t1, t2 = flight_crossings(p_lo[0], v_lo[0], wind, w)
        z1 = flight_position(p_lo[1], v_lo[1], -hopper.g, jnp.where(jnp.isfinite(t1), t1, 0.0))
        z2 = flight_position(p_lo[1], v_lo[1], -hopper.g, jnp.where(jnp.isfinite(t2), t2, 0.0))
        return (((t1 <= t_up) & (z1 < terrain.heights))
                | ((t2 <= t_up) & (z2 < terrain.heights)))

    return ~jnp.any(wall_hit(terrain.starts) | wall_hit(terrain.ends))


def stride_clear(th, foot, z_min, p_lo, v_lo, terrain: Terrain, hopper: Hopper, wind=0.0):
    """Whether a stance with the foot at `foot = (y_foot, h)` keeps its COM (lowest at
    `h + z_min`) above every block it passes over, and the rise from liftoff (`p_lo`,
    `v_lo`, world frame) crosses no wall below its top and rises at all."""
    y_td = foot[0] - hopper.rho0 * jnp.sin(th)
    lo, hi = jnp.minimum(y_td, p_lo[0]), jnp.maximum(y_td, p_lo[0])
    sweep = jnp.any((terrain.heights > foot[1] + z_min) & (terrain.starts < hi)
                    & (terrain.ends > lo))
    return ~sweep & _rise_clear(p_lo, v_lo, terrain, hopper, wind) & (v_lo[1] > 0)


def slip_stride(apex, u, terrain: Terrain, hopper: Hopper, wind=0.0,
                tol: Tolerances = STRIDE_TOL, energy=None):
    """One SLIP stride on the terrain: descent, touchdown, stance, rise to the next apex.

    The foot rides at `COM + rho0 (sin th_td, -cos th_td)` from apex and lands on the first
    block it meets (`touchdown`, which also reports walls, holes and leaving the map). The
    stance runs on that block. The COM must stay above every block it passes over in stance
    (checked at its lowest sampled height: touchdown, bottom, liftoff) and must not cross a
    wall below its top on the way up. Wind acts in flight only.

    Arguments:
        apex: `(y, z, ydot)`.
        u: `(th_td, kc, kd)`.
        energy: if given and finite, the target apex energy: `kd` is then computed at the
            bottom of the stance from the actual state (`bottom_kd`, eq 12 with the
            compression that happened), not taken from `u`.

    Returns:
        `(next_apex, code, foothold)` with `foothold = (y_foot, h)`.
    """
    th, kc, kd = u
    offset = hopper.rho0 * jnp.stack([jnp.sin(th), -jnp.cos(th)])
    code, block, _, y_foot, v_td = touchdown(apex, offset, terrain, hopper, wind)
    h = terrain.heights[block]
    landed = code == OK
    # Failed descents run a benign dummy stance instead of an arbitrary one.
    st = stance(jnp.where(landed, th, 0.0), jnp.where(landed, v_td, jnp.array([0.0, -1.0])),
                kc, kd, hopper, tol, energy, h)
    foot = jnp.stack([y_foot, h])
    p_lo = st.p_lo + foot
    clear = stride_clear(th, foot, st.z_min, p_lo, st.v_lo, terrain, hopper, wind)
    nxt = ascent(p_lo, st.v_lo, hopper, wind)
    code = jnp.where(~landed, code, jnp.where(st.code != OK, st.code,
                                              jnp.where(clear, OK, COLLISION)))
    return nxt, code, foot


slip_stride_jit = jit(slip_stride)
slip_apex_map_jit = jit(slip_apex_map)


_STRIDE_CHUNK = 512


def slip_strides(apex, u, terrain: Terrain, hopper: Hopper, wind=0.0,
                 tol: Tolerances = STRIDE_TOL):
    """Many SLIP strides: `slip_stride` vmapped, in chunks of 512 over all local devices.

    A vmapped diffrax solve steps every lane until the slowest lane of its batch ends;
    chunks of 512 waste fewer steps than one large batch, and on a CPU each device uses
    about one core (`chunked_map`).

    Arguments:
        apex, u: `(n, 3)` arrays.

    Returns:
        `(next_apex, code, foothold)` as NumPy arrays with `n` rows.
    """
    apex, u = np.atleast_2d(np.asarray(apex, float)), np.atleast_2d(np.asarray(u, float))
    if apex.shape != u.shape or apex.shape[1:] != (3,):
        raise ValueError(f"apex and u must both be (n, 3), got {apex.shape} and {u.shape}")
    return chunked_map(_strides_jit, apex.shape[0], _STRIDE_CHUNK, (apex, u),
                       (terrain, hopper, wind, tol))


_strides_jit = jit(jax.vmap(slip_stride, (0, 0, None, None, None, None)))
