r"""Stick-slip friction with a proxy: the tip stays stuck inside the friction cone.

Haptic rendering represents friction with a proxy (god-object) that sticks to the surface while
the tangential force stays inside the static friction cone and slides along the cone's edge
when pushed out of it (Zilles & Salisbury 1995; Ruspini, Kolarov & Khatib 1997; CHAI3D's proxy
algorithm; the elasto-plastic "bristle" of Hayward & Armstrong 2000). No velocity appears in
the law, so nothing is differentiated from a position that the rendered force itself moves.

The proxy is an *anchor* :math:`A`: where the tip centre would be with the tangential spring
relaxed. With the tip centre :math:`c`, the unit normal :math:`n` and the tangential offset
:math:`d = (c - A) - ((c - A)\cdot n)\,n`, a tangential spring of stiffness :math:`k_t` holds
the tip:

.. math::

    F_t = -k_t\,d \quad \text{(stuck, } k_t\lVert d\rVert \le f_s\text{)}, \qquad
    F_t = -f_k\,\hat d,\quad A \leftarrow c - \frac{f_k}{k_t}\,\hat d
    \quad \text{(slipping)},

with the static and kinetic limits :math:`f_s = \mu_s N \ge f_k = \mu_k N` of the friction law
(:func:`friction_limits`). The proxy has no mass, so a slip takes no time: pushed out of the
static cone, the anchor slides until the stretch has relaxed to the kinetic cone
(:math:`k_t\lVert d\rVert = f_k`) and the contact sticks there again - the usual friction proxy
with two cones (Salisbury et al. 1995, "Haptic rendering: programming touch interaction with
force-feedback devices": stick inside the static cone, move to the edge of the dynamic one when
pushed out; Hayward & Armstrong 2000). :math:`k_t` is the tangential contact stiffness of Mindlin (1949),
:math:`k_t = 8 G^* a`, which for like materials is
:math:`k_t = \frac{2(1-\nu)}{2-\nu}\,2 E^* a` (Johnson, *Contact Mechanics*, 1985, Sec. 7.2),
in series with the virtual coupling's stiffness when there is one.

*Saw-tooth.* With :math:`\mu_s > \mu_k` a tip sliding at speed :math:`v` (ticks of
:math:`\Delta t`) sticks right after each slip with the stretch at the kinetic cone; the friction
then grows by :math:`k_t v \Delta t` per tick until it would leave the static cone, where it slips
back to :math:`f_k`. The stuck ticks after a slip number :math:`\lfloor (f_s - f_k) / (k_t v \Delta t)\rfloor`,
so the friction is a saw-tooth from :math:`f_k` up to at most :math:`f_s` (amplitude
:math:`f_s - f_k = (\mu_s - \mu_k) N` less at most one tick's rise :math:`k_t v \Delta t`) with the period

.. math::

    T = \Delta t \left(\left\lfloor \frac{(\mu_s - \mu_k)\,N}{k_t\,v\,\Delta t} \right\rfloor + 1\right)
    \;\approx\; \frac{(\mu_s - \mu_k)\,N}{k_t\,v} + \Delta t,

the time the tip takes to stretch the spring across the gap between the two cones, rounded up to
the tick. With :math:`\mu_s = \mu_k` the gap is zero: every moving tick slips at :math:`f_k` and
a steady slide carries exactly :math:`\mu_k N`, without teeth; a tip pressed still on a slope
flatter than the static cone stays put and feels a steady force.

*Friction law* (the normal :math:`N`, :data:`LAW_NAMES`): ``"adhesive"`` (the default),
:math:`N = P + |P_c|` with :math:`P_c` the Maugis-Dugdale pull-off force of the local law, so a
tip held by adhesion still resists sliding under a tensile load, down to the pull-off; [Alabdulmuhsin]
writes the friction as :math:`\mu N + A`, and AFM friction on single asperities follows the
contact area, which stays finite under tensile load until the pull-off (Carpick & Salmeron 1997,
"Scratching the surface: fundamental investigations of tribology with atomic force microscopy",
Chem. Rev. 97, 1163). ``"area"``: that proportionality itself, :math:`f_k = \tau \pi a^2` with an
interfacial shear strength :math:`\tau` (Pa) and :math:`f_s = (\mu_s / \mu_k) f_k`.
``"compressive"``: :math:`N = \max(P, 0)`, friction only under a compressive load (the law of
sessions recorded before the friction law was recorded; their replay uses it).

The *friction direction* the decoupling of measured signals needs is read off the proxy, never
differentiated from positions: the slip direction while the contact slides, the direction of the
static friction's own pull (:math:`\hat d`) while it sticks, with the friction's *strength*
:math:`s = \lVert F_t\rVert / f_k` (1 when sliding). The model fades the decoupling from its
no-motion fallback to the directional solution as :math:`s` grows (:mod:`arsurf.model`), so a tip
standing still - whose offset from the anchor is tiny and points anywhere as it jitters - gets
the no-motion answer steadily, and nothing jumps when the hand starts or stops pushing sideways.

*The tip's displacement, not the closest point's.* Mindlin's :math:`k_t` relates the tangential
force to the rigid tangential displacement of the indenter against the substrate (Johnson 1985,
Sec. 7.2): the stretch is how far the tip itself has moved along the surface since it stuck. The
closest point of the surface is a geometric point, not a material one, and was measured instead
until 2026-11-28: it jumps from asperity to asperity while the tip moves a picometre (the anchor
had to be carried along each jump, found by a basin test), and in a hollow about as wide as the
tip it runs ahead of the tip (by :math:`\rho/(\rho - R)` on a curvature radius :math:`\rho`), so the
same stuck contact felt stiffer and turned with the hollow's normals. The spring it made was
not a gradient: sliding at 1 nm/s through a 7 nm rough patch under a 3.4 nm tip the hand got
11 times the passive store back (tests/haptics/test_feel_families.py). The anchor also follows
the tip along the normal every tick - the spring stretches only tangentially - so a press since
the stick began does not turn into a tangential stretch when the normal turns (without it, a tip
pressed 7 nm into a slope and held there rocked across it: 320 force reversals).

State (4 floats, part of the model state): the anchor x, y, z (m; NaN: none, set at the first
contact tick) and the slip flag (1: the contact slipped on the last tick).
"""
from __future__ import annotations

import math

from numba import njit

from arsurf._layout import Layout

#: the proxy's state (m; the slip flag 0 or 1), part of the state vector given to
#: :func:`stick_slip_kernel` (at an offset)
FRICTION_STATE = Layout("friction state", [("anchor", 3), ("slipping", 1)])
#: what :func:`stick_slip_kernel` writes: the friction force on the tip (N), the friction direction
#: (unit: the tip's motion over the surface; zeros: none), the strength |F_t| / f_k (the kinetic limit)
FRICTION_OUT = Layout("friction output", [("force", 3), ("direction", 3), ("strength", 1)])
# the offsets as the kernel uses them
ANCHOR, SLIPPING = FRICTION_STATE.offset("anchor"), FRICTION_STATE.offset("slipping")
STATE_SIZE = FRICTION_STATE.size
O_FORCE, O_DIRECTION, O_STRENGTH = (FRICTION_OUT.offset("force"), FRICTION_OUT.offset("direction"),
                                    FRICTION_OUT.offset("strength"))
OUT_SIZE = FRICTION_OUT.size
#: the friction laws (module docstring): their codes in the proxy parameters, by name
LAW_COMPRESSIVE, LAW_ADHESIVE, LAW_AREA = 0, 1, 2
LAW_NAMES = {"compressive": LAW_COMPRESSIVE, "adhesive": LAW_ADHESIVE, "area": LAW_AREA}
#: ratio of Mindlin's tangential to the normal contact stiffness for like materials with
#: Poisson's ratio 0.3: 2 (1 - nu) / (2 - nu) (Johnson 1985, Sec. 7.2)
MINDLIN_RATIO = 2.0 * (1.0 - 0.3) / (2.0 - 0.3)


@njit(cache=True)
def friction_limits(law, mu_s, mu_k, load, pull_off, shear_strength, radius):
    r"""The static and kinetic friction limits ``(f_s, f_k)`` (N) of a contact (module docstring).

    ``law`` a code of :data:`LAW_NAMES`; ``load`` P (N, > 0 compressive), ``pull_off`` the
    magnitude :math:`|P_c|` of the law's pull-off force (N), ``shear_strength`` :math:`\tau` (Pa,
    area law), ``radius`` the contact radius a (m). Load laws: :math:`f = \mu N` with
    :math:`N = \max(P + |P_c|, 0)` (adhesive) or :math:`\max(P, 0)` (compressive); area law:
    :math:`f_k = \tau\pi a^2`, :math:`f_s = (\mu_s/\mu_k) f_k`."""
    if law == LAW_AREA:
        fk = shear_strength * math.pi * radius * radius
        return (fk * mu_s / mu_k if mu_k > 0.0 else fk), fk
    normal = load + pull_off if law == LAW_ADHESIVE else load
    normal = max(normal, 0.0)
    return mu_s * normal, mu_k * normal


@njit(cache=True)
def release(state, at) -> None:
    """Forget the anchor (out of contact): ``state[at:at + STATE_SIZE]``."""
    for j in range(STATE_SIZE):
        state[at + j] = math.nan
    state[at + SLIPPING] = 0.0


@njit(cache=True)
def stick_slip_kernel(cx, cy, cz, nx, ny, nz, f_static, f_kinetic, k_t, state, at, out):
    r"""One tick of the stick-slip proxy (module docstring).

    ``c`` the tip centre (m), ``n`` the unit contact normal, the static and kinetic friction limits
    ``f_static >= f_kinetic >= 0`` (N: :math:`\mu_s N`, :math:`\mu_k N` of the friction law,
    :func:`friction_limits`), ``k_t`` the tangential stiffness (N/m, > 0);
    ``state[at:at + STATE_SIZE]`` (updated). Writes ``out`` (:data:`FRICTION_OUT`): the friction
    force on the tip (N), the friction direction (unit: the tip's motion over the surface, opposite
    to the friction; zeros: none) and the strength :math:`\lVert F_t\rVert / f_k` (1 when
    slipping). Returns 1 when the contact slipped this tick, else 0."""
    for j in range(OUT_SIZE):
        out[j] = 0.0
    if not math.isfinite(state[at + ANCHOR]):
        state[at + ANCHOR] = cx
        state[at + ANCHOR + 1] = cy
        state[at + ANCHOR + 2] = cz
        state[at + SLIPPING] = 0.0
        return 0
    dx = cx - state[at + ANCHOR]
    dy = cy - state[at + ANCHOR + 1]
    dz = cz - state[at + ANCHOR + 2]
    dn = dx * nx + dy * ny + dz * nz
    dx -= dn * nx
    dy -= dn * ny
    dz -= dn * nz
    state[at + ANCHOR] += dn * nx  # the anchor follows the tip along the normal (module docstring)
    state[at + ANCHOR + 1] += dn * ny
    state[at + ANCHOR + 2] += dn * nz
    d = math.sqrt(dx * dx + dy * dy + dz * dz)
    if k_t * d <= f_static or d == 0.0:  # stuck: inside the static cone
        out[O_FORCE] = -k_t * dx
        out[O_FORCE + 1] = -k_t * dy
        out[O_FORCE + 2] = -k_t * dz
        state[at + SLIPPING] = 0.0
        if d > 0.0:
            out[O_DIRECTION] = dx / d
            out[O_DIRECTION + 1] = dy / d
            out[O_DIRECTION + 2] = dz / d
            out[O_STRENGTH] = k_t * d / f_kinetic if f_kinetic > 0.0 else 0.0
        return 0
    ux = dx / d
    uy = dy / d
    uz = dz / d
    # the massless proxy slips at once: the anchor slides until the stretch has relaxed to the
    # kinetic cone, where the contact sticks again (re-sticking: the saw-tooth when mu_s > mu_k)
    back = f_kinetic / k_t
    state[at + ANCHOR] = cx - back * ux
    state[at + ANCHOR + 1] = cy - back * uy
    state[at + ANCHOR + 2] = cz - back * uz
    state[at + SLIPPING] = 1.0
    out[O_FORCE] = -f_kinetic * ux
    out[O_FORCE + 1] = -f_kinetic * uy
    out[O_FORCE + 2] = -f_kinetic * uz
    out[O_DIRECTION] = ux
    out[O_DIRECTION + 1] = uy
    out[O_DIRECTION + 2] = uz
    out[O_STRENGTH] = 1.0
    return 1
