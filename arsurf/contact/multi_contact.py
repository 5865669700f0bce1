r"""Several contacts at once: the tip sphere resting on two, three or four asperities.

A tip wider than a valley rests on both of its slopes. The closest point of the surface to the
tip centre C then jumps from one slope to the other as C crosses the valley (it may alternate
tick after tick while the hand holds still), and a force computed at the closest point alone
flips with it. A rigid sphere there touches the surface at every *local* minimum of the
distance :math:`d(u, v) = \lVert S(u, v) - C\rVert` inside the contact zone, and feels the sum of
their loads: the closest point may jump, the force may not.

This is the haptics field's classic problem of concave corners: the god-object keeps up to
three active constraints at once (Zilles & Salisbury 1995, "A constraint-based god-object method
for haptic display", IROS), and a sphere proxy finds the position where all its active contacts
hold (Ruspini, Kolarov & Khatib 1997, "The haptic display of complex graphical environments",
SIGGRAPH). Here each constraint is a Maugis-Dugdale contact instead of a rigid plane.

**Finding the contacts** (:func:`find_contacts_kernel`, at most :data:`MAX_CONTACTS`). Row 0 is
the global closest point of the collision query (exact: hull tree + Newton). Newton's method
(:func:`~arsurf.contact.newton.newton_box`) is run from the contacts of the previous tick
(tracking), from where the collision query's own Newton run from the previous closest point
ended (``OUT_WARM_U``/``OUT_WARM_V``: the old basin when the closest point jumped), and from
every local minimum of the control net's distance to C within reach (*discovery*,
:func:`_discover`: the control points within R plus the interaction range and two knot
spacings of C, each compared with its eight neighbours; the closest such minima are Newton starts,
:data:`DISCOVERY_STARTS` runs at most, passing over a minimum next to a contact already in the
table (it is that contact's: with more minima in reach than runs, the runs went to the same
closest ones at every scan and a contact beyond them was never found - 12 of a ring of 14 bumps,
tests/contact/test_multi_contact.py), each kept within :data:`START_REACH` knot spacings of its start, so
that it finds the surface's minimum next to the net's and not one its path reaches nanometres away:
unbounded, which minima a first touch found changed with a picometre of height - on the PeakForce
scan sample_0.spm under its 5 nm tip a minimum 0.59 nm deep came and went, and the load with it by
3.5 %; beyond :data:`DISCOVERY_NODES` points in reach the net is read at a
coarser stride). The net is scanned at the first touch and again whenever the tip centre has
moved :data:`SCAN_EVERY` weight margins m (below) since the last scan - a minimum that comes
within reach or is born between two scans is followed from then on by tracking - so the contacts
found depend on where the tip is, not on how it got there: the force is the same whether the
hand's path was sampled at 1 or at 10 kHz (a single discovery start per tick, in turn, which this replaced,
found a minimum one tick and missed it the next depending on the step: the same point reached
by steps of 0.01 or 1 nm felt forces up to 35 % apart on rough Gaussian surfaces, and a 1 kHz
slide at 1000 nm/s differed from the same slide at 10 kHz by 39 %;
tests/contact/test_multi_contact.py, docs/feel-log.rst).
Every converged end whose depth :math:`\delta_i = R - (C - S_i)\cdot n_i` (along its own normal
:math:`n_i`, out of the sample) is within the interaction range and at most R is a contact (a
minimum with :math:`(C - S_i)\cdot n_i < 0` has the centre behind its patch, inside the
material there: a steep wall the target passed behind when a soft coupling lets the hand press
deeper than the tip radius - not a point the sphere rests on from outside; on a steep
power-law surface such a "contact" 9.6 nm deep under a 5.6 nm tip drove the press to -54 E0;
the sign of :math:`(C - S_i)\cdot n_i = \pm d_i` changes only where :math:`d_i`, and so the
closest distance, is 0); ends within :data:`SAME_POINT` knot spacings of
one already found are the same contact (found from two starts) and merged.

**Weights: continuity across the hop and at birth/death.** A local minimum is born and dies at a
fold of the distance function, where it merges with the saddle (or ridge) that separates it from
its neighbour: its barrier :math:`b_i = s_i - d_i` goes to 0 there, :math:`s_i` the highest
distance on the way from contact i to the closest point (sampled at :data:`PATH_SAMPLES`
points of the straight (u, v) segment between them: a continuous lower bound of the pass that
vanishes with the true barrier). On the same pass the closest point's barrier is
:math:`b_i' = s_i - d_1 \ge b_i`. With :math:`r(x) = \min(x/m, 1)`, m the margin (a fraction of
the contact law's depth scale), contact i > 0 and the closest point count with

.. math:: w_i = \varphi(b_i, b_i'), \qquad w_1 = \prod_{i>1} \varphi(b_i', b_i), \qquad
          \varphi(b, b') = r(b) + (1 - r(b))\,\frac{b}{b + b'} .

:math:`\varphi(0, b') = 0`: a contact is born and dies with no weight, and its neighbour keeps
:math:`\varphi(b', 0) = 1`; two minima separated by a pass m high count fully (1 + 1); and
:math:`\varphi` is symmetric in the pair, so when the closest point hops to contact i (equal
depths) the two swap rows with equal weights and the sum does not step. Near a cusp, where two
minima and their pass merge into one (a contact patch the tip touches along a flat or concave
stretch), the two weights sum to :math:`1 + 2bb'/(m(b + b'))`, close to 1: one contact, not two
full loads, and their sum changes by at most 2/m per unit of distance even where each weight
changes quickly (a ratio of barriers, :math:`r(b_i)/r(b_i')`, was continuous too, but let a
contact born next to the closest point just before a hop swing from 0.4 to 0.05 in three ticks,
a spike of the summed load).

**One contact of a rough tip.** Two minima whose contact discs overlap strongly are not two
contacts: a scan's roughness at the scale of the contact leaves several minima of the distance
inside one contact (on the PeakForce scan sample_0.spm under its 5 nm tip at 2 nN, four minima
within 1.2 nm of each other under a contact of radius a = 2.7 nm on the stiff spot, 5.7 nm on the
soft one), and the half-space under the tip carries one contact there: the Maugis-Dugdale
traction, compressive inside a and adhesive out to the Dugdale zone's edge c, is spread over
that disc, so a second minimum inside it adds no second load (counting every minimum took 1.83
nN where one contact carries 2.0 nN; weighing by the disc of radius a alone still counted the
adhesion of minima inside the zone at pull-off: -8.8 nN for the law's -7.1 nN). Contact i > 0,
at distance :math:`s_i` from the closest point, is therefore weighed by

.. math:: o_i = \min(\max(s_i/c - 1, 0), 1),

c the closest contact's Dugdale-zone radius at its depth under the tip: the law's :math:`c(\delta_c)`
at the depth :math:`\delta_c` the closest contact alone takes behind the coupling at this target
(:func:`~arsurf.contact.proxy.coupled_depth_kernel`; a function of where the target is - the depth at
the previous tick's lift, used first, fed the zone back through the weights into the next lift, and
a target held still got forces up to 1.5 times apart from one tick to the next), on the branch
connected to contact: the cohesive zone still holds the tip where the contact radius has reached 0,
so c does not vanish there - it did, and a tip held at that depth flipped between one and two
contacts every tick; c is 0 only once the tip has let go: 0 while each point
lies inside the other's zone (:math:`s_i \le c`: one contact, exactly the single contact's load
and depth), 1 once the two zones are apart (:math:`s_i \ge 2c`: two contacts), linear between so
the force stays continuous as the separation changes: contact i counts with
:math:`o_i\,\varphi(b_i, b_i')`, the closest point with
:math:`\prod_i (o_i\,\varphi(b_i', b_i) + 1 - o_i)`.

**A hop inside one zone.** The closest point may still hop between two minima inside one zone
(sample_0.jpk: two minima 2.3 nm apart under one 6.5 nm contact). The merged contact keeps the
single contact's load :math:`P(\delta_1)` (continuous through the swap: the largest depth) and
shares only its direction, with the same symmetric pair weights and each point's Hertz share
:math:`q_i` (:func:`hertz_share`): the closest contact pushes :math:`P(\delta_1)\,V_1`,

.. math:: V_1 = w_1\,\mathrm{unit}\Big(w_1\,\omega_1\,q_1 n_1 + \sum_{i>1} (1 - o_i)\,\varphi(b_i, b_i')\,q_i n_i\Big),
          \qquad \omega_1 = \prod_{i>1} \big((1 - o_i)\,\varphi(b_i', b_i) + o_i\big):

the mean of the members' normals, each by its pair weight and its Hertz share. For a pair with
o = 0 it is :math:`\mathrm{unit}(\varphi(b_2', b_2)\,q_1 n_1 + \varphi(b_2, b_2')\,q_2 n_2)`,
symmetric, so the swap changes nothing (without :math:`\omega_1` the closest point's own normal
counted with 1 against the other's :math:`\varphi < 1` where the pass between them is lower than
m: on sample_0.spm under its 5 nm tip two minima as deep as each other split 55/45 towards
whichever was closest, and the hop turned the force by 0.015 rad in one tick); a minimum born or
dying at a fold turns nothing
(:math:`\varphi(0, b') = 0`); a shallower minimum's share fades over the Hertz share, a ramp of
the order of the contact's own depth (a depth ramp of m/10 was crossed within one tick at 150
nm/s); a member leaving the zone (:math:`o_i \to 1`) leaves the mean as it becomes a contact of
its own. With more than two members the mean is the same from any member, up to the barriers of
minima being born. (The first form turned the closest normal pair by pair,
:math:`\mathrm{unit}(n_1 + \sum_i (m_i - n_1))` with :math:`m_i` each pair's mean: with N
members that subtracts the closest point's normal N - 2 times, so six minima of one rough contact
pushed along a direction that swung by tens of degrees whenever the closest point hopped among
them, or the second reference below took over: 3 reversals in a 0.1 nm/s slide on a 0.5 nm
power-law surface under a 5.8 nm tip, now 0.)

**A hop between two contacts.** Every weight above is measured from the closest point. When it
hops between two minima as deep as each other, a third minimum's distance and pass to it jump
(on a power-law surface under a 6.9 nm tip, three minima 5-8 nm from one of two equal contacts
and 13-15 nm from the other went from partly merged to apart within 0.4 pm of travel, and the
force doubled; the loop then crossed that hop every three or four ticks: 453 reversals in a 1
nm/s slide). So the answers measured from the closest contact and from the deepest other one are
averaged, weighted 1 and :math:`\pi`, 1 when the two are as deep and 0 from one margin m
shallower (:func:`weigh_contacts_kernel`): symmetric in the two at the hop, so it changes nothing.
Where a third contact is within a margin as deep as the second, :math:`\pi` fades to 0 (the
second reference is then not one contact): a hop among three equally deep minima still steps.

**Followed from birth.** Like the god-object and the sphere proxy, which keep their active
constraints from tick to tick, each contact is re-found from its own last (u, v) (tracking):
a minimum born at a fold between two scans is followed from there, with the barrier 0 it was
born with, so its weight grows from 0. (Earlier, a minimum found late by a discovery start got
a barrier credit that grew no faster than the tip moved; with the whole net scanned the credit
only made the force depend on the path - a contact lost by tracking at a large step and found
again started from 0 - and it was removed.)

**Entry at the edge.** A contact also enters and leaves the table through its depth: an
asperity comes within reach as the tip approaches it, and one found by a scan may already be
in reach. The law itself steps there: under an interacting tip, the
Maugis-Dugdale load jumps from 0 to the adhesive :math:`P(\delta_{out}) \ne 0` at the jump-out
depth. Each contact i > 0 therefore also carries an entry ramp on its depth at the tip,

.. math:: e_i = \min\Big(\frac{r_d(\delta_i - \delta_{out})}{r_d(\delta_1 - \delta_{out})}, 1\Big),
          \qquad r_d(x) = \min(\max(x/m, 0), 1),

0 at the jump-out depth (where the law steps: the contact enters and leaves with no force), 1
from m deeper on, and 1 when it is as deep as the closest contact (the hop swaps two equal rows
again). The total normal force is then

.. math:: F_N = P(\delta_1)\,V_1 + \sum_{i>1} w_i\,e_i\,P(\delta_i)\,n_i ,

each :math:`P` the Maugis-Dugdale load at the contact's own depth, all under one rigid tip: a
contact that grows in enters with no step, and a secondary contact's adhesion grows with its
depth instead of snapping in (its own snap-in would be a step of the load every time the tip
slides onto an asperity).

**One tip behind the coupling.** The tip moves behind the virtual coupling along the total
normal :math:`n = (q_1 V_1 + \sum_{i>1} w_i q_i n_i) / \lVert\cdot\rVert`,
:math:`q_i = ((\delta_i - \delta_{out})_+ + 10^{-3}m)^{3/2}` (the depth beyond the jump-out depth
to the Hertz power: the direction of :math:`F_N` for similar compressive contacts, and continuous
through every change of the set of contacts), by the lift :math:`\ell` at which the coupling
balances the *summed* load, :math:`F_N(\ell)\cdot n = k_c\,\ell` (:func:`coupled_lift_kernel`):
along n every contact is in series with the coupling, so the hand never feels more than
:math:`k_c` along it however many asperities carry the tip (a contact outside the coupling would
add its whole stiffness, :math:`K_f\,s\,dP/d\delta`, to what the device renders, and buzz).
Sideways, the part r of :math:`F_N` off n is passed through the coupling too
(:func:`coupled_offset_kernel`): the tip moves in the plane normal to n by one Newton step of the
three-dimensional balance :math:`k_c\,\Delta = F_N(\Delta)` from the lift, :math:`s = (k_c I +
K_t)^{-1} r`, :math:`K_t` the summed contacts' stiffness in that plane (each contact a plane through
its point, as the god-object's constraints; symmetric part, eigenvalues held >= 0), and the hand
gets :math:`k_c s`. Where the walls of a valley are stiffer than the coupling, the hand is pulled
towards the valley's bottom with at most about :math:`k_c`: it felt the wedge's own stiffness
before, up to 14 N/m sideways behind a 5 N/m coupling in tests/contact/test_force_field.py's
valleys (now 5.1-5.3 N/m; beyond :math:`k_c` by what the contact normals turn as the target
moves), which sampled at 1 kHz gave fast slides energy: a 100 nm/s slide -136 E0 at 1 kHz against
-16 E0 at 10 kHz. One step, not Newton to convergence: the full solve stalled where an entry ramp
or the law's adhesive branch bends the balance (residuals of 2 % of the force left on alternate
ticks: reversals of 1 mN while the tip crept at 1 nm/s), and a tip solved to balance from the
previous tick's offset would stick in the valley and snap across it (Prandtl-Tomlinson; the branch
that tried it saw jumps of 3.3-3.6 nN in the same valleys); the step is continuous in its inputs.

Lipschitz bound: depths, normals and barriers are continuous in C (depths and distances are
1-Lipschitz), so the force changes between ticks by at most
:math:`\sum_i (k_i + P_i/\rho_i + 2 P_i/m)\,\lvert\Delta C\rvert` (k the contact stiffness
:math:`dP/d\delta`, :math:`\rho` the distance over which the normal turns by a radian), with
no step: halving the step halves the largest change (tests/contact/test_multi_contact.py).

**Dent.** The tick records one dent, the tip sphere's (:func:`~arsurf.contact.deformation.record_dent_kernel`,
O(1), applied when the net is read): the closest contact's zone and elastic surround along its own
normal, and the sphere's no-interpenetration guard, which presses every control point within R
of the tip axis that is inside the sphere onto it - the other contacts' zones included.

The model keeps the contact table in its state (:data:`CONTACT_TABLE`: the tracked (u, v),
point, normal, depth, weight of each contact, and their count).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from arsurf._layout import Layout
from arsurf.contact import layout as ly
from arsurf.contact.maugis_dugdale import md_contact_hysteresis_kernel, md_zone_from_depth_kernel
from arsurf.contact.newton import newton_foot
from arsurf.contact.zone_normal import zone_normal_kernel
from arsurf.spline.basis import surface_point
from arsurf.spline.knots import greville_at
from arsurf.status import SEPARATED

#: the most contacts followed at once (the god-object's three, and the minima a rough patch puts
#: within reach: on the feel table's power-law surfaces under 2-6 nm tips pressed deep, nine to
#: fourteen; a table of eight was full for most of such a slide, a deeper minimum then replacing the
#: shallowest row with its load - a step, 1-11 reversals in 3 s - and carried 8 of a ring's 10 loads,
#: tests/contact/test_multi_contact.py). A contact beyond it still replaces the shallowest.
MAX_CONTACTS = 16
#: one contact: parameters (m), point (m), unit normal, depth along its own normal (m, > 0
#: penetrating), weight in [0, 1]
CONTACT = Layout("contact", [("uv", 2), ("point", 3), ("normal", 3), ("depth", 1), ("weight", 1)])
C_U, C_PX, C_NX = CONTACT.offset("uv"), CONTACT.offset("point"), CONTACT.offset("normal")
C_V, C_DEPTH, C_WEIGHT = C_U + 1, CONTACT.offset("depth"), CONTACT.offset("weight")
C_SIZE = CONTACT.size
#: the contact table (in the model state): the count, the contacts (row 0 the closest point), the
#: previous tick's (u, v) of each (the tracking starts), the tip centre (m) of the last scan of the
#: net, the tip's last lift behind the coupling along the total normal (m; the start of the next solve),
#: the closest contact's force per unit load (its weight times the direction it pushes, turned towards
#: the minima inside its zone), and
#: the row of the second reference (-1: none), its force per unit load and the weights measured from
#: it (:func:`weigh_contacts_kernel`)
CONTACT_TABLE = Layout("contact table", [("count", 1), ("rows", MAX_CONTACTS * CONTACT.size),
                                         ("previous_uv", 2 * MAX_CONTACTS),
                                         ("scanned", 3), ("lift", 1),
                                         ("closest_force", 3), ("second", 1),
                                         ("second_force", 3), ("second_weights", MAX_CONTACTS)])
T_COUNT, T_ROWS, T_PREVIOUS = (CONTACT_TABLE.offset("count"), CONTACT_TABLE.offset("rows"),
                               CONTACT_TABLE.offset("previous_uv"))
T_SCANNED, T_LIFT = CONTACT_TABLE.offset("scanned"), CONTACT_TABLE.offset("lift")
T_CLOSEST_FORCE = CONTACT_TABLE.offset("closest_force")
T_SECOND, T_SECOND_FORCE = CONTACT_TABLE.offset("second"), CONTACT_TABLE.offset("second_force")
T_SECOND_WEIGHTS = CONTACT_TABLE.offset("second_weights")
TABLE_SIZE = CONTACT_TABLE.size
#: two converged Newton ends closer than this (in knot spacings) are the same contact
SAME_POINT = 1e-6
#: points sampled on the (u, v) segment between a contact and the closest point for its barrier
PATH_SAMPLES = 8
#: Newton iterations of the coupled lift (:func:`coupled_lift_kernel`; bisection bounds it anyway)
_MAX_LIFT_ITER = 60


@njit(cache=True)
def _row(at, i):
    return at + T_ROWS + i * C_SIZE


@njit(cache=True)
def _add(ctrl, ku, kv, ev, cx, cy, cz, radius, u, v, floor, h, tab, at, count, start_reach=math.inf):
    """Run Newton from (u, v) (within ``start_reach`` m of it in u and v); add its end as a contact
    if it converged, is new and within reach (depth >= ``floor``). Returns the new count."""
    if not (math.isfinite(u) and math.isfinite(v)):
        return count
    u, v, ax, ay, az, signed, ok = newton_foot(ctrl, ku, kv, ev, cx, cy, cz, u, v, h, start_reach)
    if not ok:
        return count
    for i in range(count):
        r = _row(at, i)
        if math.hypot(u - tab[r + C_U], v - tab[r + C_V]) <= SAME_POINT * h:
            return count  # found from another start: the same contact
    depth = radius - signed  # along its own normal, out of the sample as the collision's
    if not floor <= depth <= radius:  # out of reach, or the centre behind the patch (module docstring)
        return count
    slot = count
    if count == MAX_CONTACTS:  # full: replace the shallowest if this one is deeper
        slot = 1
        for i in range(2, MAX_CONTACTS):
            if tab[_row(at, i) + C_DEPTH] < tab[_row(at, slot) + C_DEPTH]:
                slot = i
        if not depth > tab[_row(at, slot) + C_DEPTH]:
            return count
    r = _row(at, slot)
    tab[r + C_U] = u
    tab[r + C_V] = v
    tab[r + C_PX] = ev[0, 0]
    tab[r + C_PX + 1] = ev[0, 1]
    tab[r + C_PX + 2] = ev[0, 2]
    tab[r + C_NX] = ax
    tab[r + C_NX + 1] = ay
    tab[r + C_NX + 2] = az
    tab[r + C_DEPTH] = depth
    tab[r + C_WEIGHT] = 0.0
    return min(count + 1, MAX_CONTACTS)


#: discovery: the control points within reach are scanned for local minima of their distance to the
#: tip centre; at most DISCOVERY_NODES of them (a coarser stride beyond), at most DISCOVERY_STARTS
#: Newton starts (the closest minima of the net)
DISCOVERY_NODES = 4096
DISCOVERY_STARTS = 12
#: ... taken in order of distance from this many of the closest minima, passing over those next to a
#: contact already in the table
DISCOVERY_CANDIDATES = 48
#: the discovery's scratch (:func:`find_contacts_kernel`'s ``work``): the nodes' squared distances,
#: then the candidates' (distance, a, b)
DISCOVERY_WORK = DISCOVERY_NODES + 3 * DISCOVERY_CANDIDATES
#: a discovery start's Newton stays within this many knot spacings of it (in u and v): the net's
#: minimum stands for the surface's minimum next to it, not for one Newton's path reaches farther away
START_REACH = 2.0
#: the net is scanned again once the tip centre has moved this many weight margins since the last scan
#: (between scans, tracking follows what was found; at 4 m the valley tests' largest force step still
#: halves with the tip's step, tests/contact/test_multi_contact.py)
SCAN_EVERY = 4.0


@njit(cache=True)
def _discover(ctrl, ku, kv, ev, cx, cy, cz, radius, floor, h, tab, at, count, work):
    """Add the contacts Newton finds from the local minima of the control net's distance to the tip
    centre within reach (module docstring, "Finding the contacts"): control point (i, j) stands
    at its Greville abscissae, where the undeformed surface passes near it; of the
    :data:`DISCOVERY_CANDIDATES` closest of those minima, in order, those not next to a contact in
    the table (within one node) are run, :data:`DISCOVERY_STARTS` at most; ``work`` holds
    :data:`DISCOVERY_WORK` floats. Returns the new count."""
    nu = ctrl.shape[0]
    nv = ctrl.shape[1]
    reach = radius - floor + 2.0 * h
    hu = ku[4] - ku[3]
    hv = kv[4] - kv[3]
    i0 = max(int(math.floor((cx - reach - ku[3]) / hu)), 0)
    i1 = min(int(math.ceil((cx + reach - ku[3]) / hu)) + 2, nu - 1)
    j0 = max(int(math.floor((cy - reach - kv[3]) / hv)), 0)
    j1 = min(int(math.ceil((cy + reach - kv[3]) / hv)) + 2, nv - 1)
    if i1 < i0 or j1 < j0:
        return count
    stride = 1
    while ((i1 - i0) // stride + 1) * ((j1 - j0) // stride + 1) > DISCOVERY_NODES:
        stride += 1
    ni = (i1 - i0) // stride + 1
    nj = (j1 - j0) // stride + 1
    for a in range(ni):  # work[a nj + b]: node (a, b)'s squared distance
        for b in range(nj):
            i = i0 + a * stride
            j = j0 + b * stride
            dx = ctrl[i, j, 0] - cx
            dy = ctrl[i, j, 1] - cy
            dz = ctrl[i, j, 2] - cz
            work[a * nj + b] = dx * dx + dy * dy + dz * dz
    best_d = work[DISCOVERY_NODES:DISCOVERY_NODES + DISCOVERY_CANDIDATES]
    best_a = work[DISCOVERY_NODES + DISCOVERY_CANDIDATES:DISCOVERY_NODES + 2 * DISCOVERY_CANDIDATES]
    best_b = work[DISCOVERY_NODES + 2 * DISCOVERY_CANDIDATES:DISCOVERY_WORK]
    for k in range(DISCOVERY_CANDIDATES):
        best_d[k] = math.inf
        best_a[k] = 0.0
        best_b[k] = 0.0
    r2 = reach * reach
    for a in range(ni):
        for b in range(nj):
            d = work[a * nj + b]
            if not d <= r2:
                continue
            low = True
            for da in range(-1, 2):
                for db in range(-1, 2):
                    if (da == 0 and db == 0) or not (0 <= a + da < ni and 0 <= b + db < nj):
                        continue
                    e = work[(a + da) * nj + b + db]
                    if e < d or (e == d and (da < 0 or (da == 0 and db < 0))):
                        low = False
            if not low:
                continue
            k = DISCOVERY_CANDIDATES - 1
            if not d < best_d[k]:
                continue
            while k > 0 and best_d[k - 1] > d:
                best_d[k] = best_d[k - 1]
                best_a[k] = best_a[k - 1]
                best_b[k] = best_b[k - 1]
                k -= 1
            best_d[k] = d
            best_a[k] = a
            best_b[k] = b
    runs = 0
    for k in range(DISCOVERY_CANDIDATES):
        if runs == DISCOVERY_STARTS or not math.isfinite(best_d[k]):
            break
        u = greville_at(ku, i0 + int(best_a[k]) * stride)
        v = greville_at(kv, j0 + int(best_b[k]) * stride)
        followed = False
        for i in range(count):  # a node next to a contact in the table is that contact's: no run
            r = _row(at, i)
            if abs(u - tab[r + C_U]) <= hu * stride and abs(v - tab[r + C_V]) <= hv * stride:
                followed = True
                break
        if not followed:
            count = _add(ctrl, ku, kv, ev, cx, cy, cz, radius, u, v, floor, h, tab, at, count, START_REACH * h)
            runs += 1
    return count



@njit(cache=True)
def _pass_height(ctrl, ku, kv, ev, cx, cy, cz, u1, v1, di, ui, vi):
    """s: the highest distance (m) on the (u, v) segment from contact i to the closest point (module docstring)."""
    s = di
    for k in range(1, PATH_SAMPLES + 1):
        t = k / (PATH_SAMPLES + 1.0)
        surface_point(ctrl, ku, kv, ui + t * (u1 - ui), vi + t * (v1 - vi), 0, ev)
        dx = ev[0, 0] - cx
        dy = ev[0, 1] - cy
        dz = ev[0, 2] - cz
        s = max(s, math.sqrt(dx * dx + dy * dy + dz * dz))
    return s


@njit(cache=True)
def pair_weight(own, other, margin):
    r"""The weight of a contact whose barrier is ``own`` (m) against a neighbour whose barrier on the
    same pass is ``other`` (module docstring):
    :math:`\varphi(b, b') = r(b) + (1 - r(b))\,b / (b + b')`, :math:`r(x) = \min(x/m, 1)`."""
    r = min(max(own, 0.0) / margin, 1.0)
    both = max(own, 0.0) + max(other, 0.0)
    return r + (1.0 - r) * (max(own, 0.0) / both if both > 0.0 else 0.5)


@njit(cache=True)
def find_contacts_kernel(ctrl, ku, kv, ev, cx, cy, cz, radius, floor, margin, prev_u, prev_v, tab, at, coll, work):
    """Fill the contact table ``tab[at:at + TABLE_SIZE]`` (:data:`CONTACT_TABLE`) for the tip
    centre (cx, cy, cz) of radius ``radius`` (m): row 0 the collision answer ``coll``
    (:data:`~arsurf.contact.layout.COLLISION_OUT`), then the other local minima of the distance
    deeper than ``floor`` (m; the law's interaction floor), row 0 with weight 1 and the others 0
    (their weights: :func:`weigh_contacts_kernel`; ``margin`` m sets how often the net is
    scanned, :data:`SCAN_EVERY`). ``ctrl, ku, kv``: the rest net; ``ev`` (>= 6, 3) scratch;
    ``prev_u, prev_v`` the previous closest point (NaN: none); ``work`` (:data:`DISCOVERY_WORK`)
    scratch.

    Returns the number of contacts."""
    h = max(ku[4] - ku[3], kv[4] - kv[3])
    u1 = coll[ly.OUT_U]
    v1 = coll[ly.OUT_V]
    old = int(tab[at + T_COUNT]) if tab[at + T_COUNT] == tab[at + T_COUNT] else 0
    for i in range(MAX_CONTACTS):  # the tracking starts: last tick's contacts
        r = _row(at, i)
        tab[at + T_PREVIOUS + 2 * i] = tab[r + C_U] if i < old else math.nan
        tab[at + T_PREVIOUS + 2 * i + 1] = tab[r + C_V] if i < old else math.nan
    r0 = _row(at, 0)
    tab[r0 + C_U] = u1
    tab[r0 + C_V] = v1
    for j in range(3):
        tab[r0 + C_PX + j] = coll[ly.OUT_PX + j]
        tab[r0 + C_NX + j] = coll[ly.OUT_NX + j]
    tab[r0 + C_DEPTH] = coll[ly.OUT_DEPTH]
    tab[r0 + C_WEIGHT] = 1.0
    count = 1
    # where Newton from the previous closest point ends (the collision query ran it over the same
    # domain; NaN: not known, run it here)
    wu = coll[ly.OUT_WARM_U]
    wv = coll[ly.OUT_WARM_V]
    if not (math.isfinite(wu) and math.isfinite(wv)):
        wu = prev_u
        wv = prev_v
    if math.isfinite(wu) and math.isfinite(wv) and math.isfinite(prev_u) and math.isfinite(prev_v):
        if math.hypot(wu - u1, wv - v1) > SAME_POINT * h:  # the closest point changed basins: the old one
            count = _add(ctrl, ku, kv, ev, cx, cy, cz, radius, wu, wv, floor, h, tab, at, count)
    if coll[ly.OUT_DEPTH] >= floor:  # near the surface: follow and look for the other contacts
        for i in range(1, old):  # (row 0, the previous closest point: the run above)
            count = _add(ctrl, ku, kv, ev, cx, cy, cz, radius, tab[at + T_PREVIOUS + 2 * i],
                         tab[at + T_PREVIOUS + 2 * i + 1], floor, h, tab, at, count)
        s0 = at + T_SCANNED
        since = math.sqrt((cx - tab[s0]) ** 2 + (cy - tab[s0 + 1]) ** 2 + (cz - tab[s0 + 2]) ** 2)
        if old == 0 or not since < SCAN_EVERY * margin:
            count = _discover(ctrl, ku, kv, ev, cx, cy, cz, radius, floor, h, tab, at, count, work)
            tab[s0] = cx
            tab[s0 + 1] = cy
            tab[s0 + 2] = cz
    for i in range(count, MAX_CONTACTS):
        r = _row(at, i)
        for j in range(C_SIZE):
            tab[r + j] = math.nan
    tab[at + T_COUNT] = count
    return count


@njit(cache=True)
def zone_normals_kernel(ctrl, ku, kv, ev, cx, cy, cz, radius, floor, lift, depth_scale, radius_scale, load_scale, lam,
                        t_fold, delta_fold, tab, at, count):
    """Turn the normal of each contact i > 0 of ``tab`` into the resultant over its zone
    (:func:`~arsurf.contact.zone_normal.zone_normal_kernel`, as the model does for the closest
    point): the law's Dugdale zone (``MaugisDugdale.kernel_args``) at the contact's depth under the
    tip, its depth less the closest contact's ``lift`` (m) behind the coupling."""
    for i in range(1, count):
        r = _row(at, i)
        zone = md_zone_from_depth_kernel(tab[r + C_DEPTH] - lift, depth_scale, radius_scale, load_scale, lam, t_fold,
                                         delta_fold)
        zone_normal_kernel(ctrl, ku, kv, ev, cx, cy, cz, radius, floor, tab[r + C_DEPTH], zone, tab[r + C_U],
                           tab[r + C_V], tab[r + C_NX:r + C_NX + 3])


@njit(cache=True)
def merge_factor(separation, zone):
    r"""How much a contact ``separation`` (m) from the closest point counts as a contact of its own,
    against the closest contact's Dugdale-zone radius ``zone`` c (m; <= 0: none) (module docstring,
    "One contact of a rough tip"): :math:`o = \min(\max(s/c - 1, 0), 1)`, 0 where each point lies
    inside the other's zone (s <= c), 1 where the two zones are apart (s >= 2c)."""
    if not zone > 0.0:
        return 1.0
    return min(max(separation / zone - 1.0, 0.0), 1.0)


@njit(cache=True)
def hertz_share(depth, jump_out, margin):
    r""":math:`q = ((\delta - \delta_{out})_+ + 10^{-3} m)^{3/2}`: how much a contact ``depth`` (m)
    deep pushes, relatively (the depth beyond the jump-out depth ``jump_out`` to the Hertz power;
    the small floor keeps directions continuous, and symmetric, where every contact is out of reach)."""
    return (max(depth - jump_out, 0.0) + 1e-3 * margin) ** 1.5


@njit(cache=True)
def _apart(tab, ra, rb):
    """The distance (m) between the points of the table rows starting at ``ra`` and ``rb``."""
    return math.sqrt((tab[ra + C_PX] - tab[rb + C_PX]) ** 2 + (tab[ra + C_PX + 1] - tab[rb + C_PX + 1]) ** 2
                     + (tab[ra + C_PX + 2] - tab[rb + C_PX + 2]) ** 2)


@njit(cache=True)
def _weigh_from(ctrl, ku, kv, ev, cx, cy, cz, radius, margin, zone, jump_out, tab, at, count, ref, out, stride):
    """The weights of the contacts of ``tab`` against reference contact ``ref`` (the formulas of
    :func:`weigh_contacts_kernel` with ``ref`` as the closest point), contact i's written to
    ``tab[out + i * stride]``; returns the reference's force per unit load (3 floats)."""
    r0 = _row(at, ref)
    u1 = tab[r0 + C_U]
    v1 = tab[r0 + C_V]
    d1 = radius - tab[r0 + C_DEPTH]
    n1x, n1y, n1z = tab[r0 + C_NX], tab[r0 + C_NX + 1], tab[r0 + C_NX + 2]
    q1 = hertz_share(tab[r0 + C_DEPTH], jump_out, margin)
    w0 = 1.0
    own0 = 1.0  # the reference's own pair weight in the merged direction (the members' is theirs)
    vx = vy = vz = 0.0  # the normals of the minima in the reference's zone, by their Hertz shares
    for i in range(count):
        if i == ref:
            continue
        r = _row(at, i)
        di = radius - tab[r + C_DEPTH]
        s = _pass_height(ctrl, ku, kv, ev, cx, cy, cz, u1, v1, di, tab[r + C_U], tab[r + C_V])
        o = merge_factor(_apart(tab, r, r0), zone)
        b = s - di
        own = pair_weight(b, s - d1, margin)
        other = pair_weight(s - d1, b, margin)
        tab[out + i * stride] = o * own
        w0 *= o * other + 1.0 - o
        own0 *= (1.0 - o) * other + o
        if o < 1.0:  # partly inside the reference's zone: one contact, whose direction it shares
            qi = (1.0 - o) * own * hertz_share(tab[r + C_DEPTH], jump_out, margin)
            vx += qi * tab[r + C_NX]
            vy += qi * tab[r + C_NX + 1]
            vz += qi * tab[r + C_NX + 2]
    tab[out + ref * stride] = w0
    vx += w0 * own0 * q1 * n1x
    vy += w0 * own0 * q1 * n1y
    vz += w0 * own0 * q1 * n1z
    vn = w0 / math.sqrt(vx * vx + vy * vy + vz * vz)  # the reference's load, w_1 P_1, turned
    return vn * vx, vn * vy, vn * vz


@njit(cache=True)
def _blend(ax, ay, az, bx, by, bz, beta):
    """(1 - beta) a + beta b with the length blended the same way: the mean of the two lengths
    along the direction of the mean vector (3 floats)."""
    mx = (1.0 - beta) * ax + beta * bx
    my = (1.0 - beta) * ay + beta * by
    mz = (1.0 - beta) * az + beta * bz
    mn = math.sqrt(mx * mx + my * my + mz * mz)
    if mn <= 0.0:
        return mx, my, mz
    s = ((1.0 - beta) * math.sqrt(ax * ax + ay * ay + az * az) + beta * math.sqrt(bx * bx + by * by + bz * bz)) / mn
    return s * mx, s * my, s * mz


@njit(cache=True)
def weigh_contacts_kernel(ctrl, ku, kv, ev, cx, cy, cz, radius, margin, zone, jump_out, tab, at, count):
    r"""The weights of the ``count`` contacts of ``tab`` (:func:`find_contacts_kernel`) for the tip
    centre (cx, cy, cz) (module docstring): against a reference contact (the closest point), contact
    i counts with :math:`o_i\,\varphi(b_i, b_i')`, the reference with
    :math:`w_1 = \prod_{i} (o_i\,\varphi(b_i', b_i) + 1 - o_i)`, :math:`o_i` the
    :func:`merge_factor` of its distance from the reference against ``zone`` (m, the closest
    contact's Dugdale-zone radius c at its depth under the tip), and the reference pushes along
    (per unit load) :math:`V_1 = w_1 \mathrm{unit}(w_1 \omega_1 q_1 n_1 + \sum_i (1 - o_i) \varphi(b_i, b_i') q_i n_i)`,
    :math:`\omega_1 = \prod_i ((1 - o_i)\,\varphi(b_i', b_i) + o_i)` the closest point's own pair weight
    (module docstring, "A hop inside one zone"; q: :func:`hertz_share` at ``jump_out`` m).

    **Two references.** Every term is measured from the reference, and the closest point hops
    between two minima as deep as each other: the third contacts' distances and passes to it
    jump there (minima 6-8 nm from one and 13-15 nm from the other merged by 0.3-0.9 of a zone,
    then by none: the force doubled within 0.4 pm of travel, and the loop cycled across the hop
    every three or four ticks). So the deepest other contact k is a second reference, with
    :math:`\pi = r(m - (\delta_1 - \delta_k))\,r(\delta_k - \delta_l)\,\varphi(b_k, b_k')` (0 from
    one margin m shallower than the closest, 0 where the next deepest contact l is as deep as k -
    where the choice of k changes - and 0 where k is born, with its pair weight; the same at the
    hop seen from either side): each contact's force per unit load is the mean of the two references' answers
    with weights 1 and :math:`\pi` (the closest's :math:`V_1` with its weight as a contact of
    k; k's weight times its normal with its :math:`V_k`, whose part inside the closest contact's
    zone, :math:`1 - o_k`, is pushed by that contact's load: two minima of one contact stay one
    contact, of the deepest one's load), symmetric in the two when they are as deep, so a hop
    between them changes nothing. Written: the weights (``C_WEIGHT``: for the two
    references the length of their force per unit load), ``T_CLOSEST_FORCE`` (row 0's),
    ``T_SECOND`` (k's row, -1: none), ``T_SECOND_FORCE`` (k's force per unit load) and
    ``T_SECOND_WEIGHTS`` (the weights measured from k).
    ``margin`` m, ``ev`` (>= 1, 3) scratch."""
    wt = at + T_ROWS + C_WEIGHT  # the weights from the closest point, in place in the rows
    vx, vy, vz = _weigh_from(ctrl, ku, kv, ev, cx, cy, cz, radius, margin, zone, jump_out, tab, at, count, 0,
                             wt, C_SIZE)
    r0 = _row(at, 0)
    alt = -1  # the deepest other contact, and the depth of the next (the choice of alt changes there)
    next_depth = -math.inf
    for i in range(1, count):
        d = tab[_row(at, i) + C_DEPTH]
        if alt < 0 or d > tab[_row(at, alt) + C_DEPTH]:
            if alt > 0:
                next_depth = tab[_row(at, alt) + C_DEPTH]
            alt = i
        elif d > next_depth:
            next_depth = d
    pi = 0.0
    if alt > 0:
        da = tab[_row(at, alt) + C_DEPTH]
        pi = _ramp(margin - (tab[r0 + C_DEPTH] - da), margin) * _ramp(da - next_depth, margin)
        if pi > 0.0:  # and its weight as a minimum of its own against the closest (0 at birth)
            ra = _row(at, alt)
            d0, dk = radius - tab[r0 + C_DEPTH], radius - da
            s = _pass_height(ctrl, ku, kv, ev, cx, cy, cz, tab[r0 + C_U], tab[r0 + C_V], dk, tab[ra + C_U], tab[ra + C_V])
            pi *= pair_weight(s - dk, s - d0, margin)
    tab[at + T_SECOND] = -1.0
    if pi > 0.0:
        w2 = at + T_SECOND_WEIGHTS
        ax, ay, az = _weigh_from(ctrl, ku, kv, ev, cx, cy, cz, radius, margin, zone, jump_out, tab, at, count, alt,
                                 w2, 1)
        beta = pi / (1.0 + pi)
        ra = _row(at, alt)
        # the part of k's own answer inside the closest contact's zone is that contact's: its load P_1
        o = merge_factor(_apart(tab, ra, r0), zone)
        # each blended with its length and its direction apart: two unit pushes of one merged
        # contact, seen from either reference, average to a unit push (a plain mean is shorter)
        c0 = tab[w2]  # the closest point's weight as a contact of k
        vx, vy, vz = _blend(vx, vy, vz, c0 * tab[r0 + C_NX] + (1.0 - o) * ax,
                            c0 * tab[r0 + C_NX + 1] + (1.0 - o) * ay, c0 * tab[r0 + C_NX + 2] + (1.0 - o) * az,
                            beta)
        wk = tab[ra + C_WEIGHT]
        ax, ay, az = _blend(wk * tab[ra + C_NX], wk * tab[ra + C_NX + 1], wk * tab[ra + C_NX + 2],
                            o * ax, o * ay, o * az, beta)
        for i in range(1, count):
            r = _row(at, i)
            tab[r + C_WEIGHT] = (1.0 - beta) * tab[r + C_WEIGHT] + beta * tab[w2 + i]
        tab[ra + C_WEIGHT] = math.sqrt(ax * ax + ay * ay + az * az)
        tab[at + T_SECOND] = alt
        tab[at + T_SECOND_FORCE] = ax
        tab[at + T_SECOND_FORCE + 1] = ay
        tab[at + T_SECOND_FORCE + 2] = az
    tab[r0 + C_WEIGHT] = math.sqrt(vx * vx + vy * vy + vz * vz)
    f = at + T_CLOSEST_FORCE
    tab[f] = vx
    tab[f + 1] = vy
    tab[f + 2] = vz


@njit(cache=True)
def _pushes(tab, at, i):
    """Contact i's force per unit load (3 floats): the closest contact's (i = 0, ``T_CLOSEST_FORCE``),
    the second reference's own (:func:`weigh_contacts_kernel`), or its weight times its normal."""
    if i == 0:
        f = at + T_CLOSEST_FORCE
        return tab[f], tab[f + 1], tab[f + 2]
    if i == tab[at + T_SECOND]:
        f = at + T_SECOND_FORCE
        return tab[f], tab[f + 1], tab[f + 2]
    r = _row(at, i)
    w = tab[r + C_WEIGHT]
    return w * tab[r + C_NX], w * tab[r + C_NX + 1], w * tab[r + C_NX + 2]


@njit(cache=True)
def total_normal_kernel(tab, at, count, jump_out, margin):
    r"""The total normal n (unit) of the contacts in ``tab`` (module docstring): the sum of the
    closest contact's force per unit load :math:`V_1` (``T_CLOSEST_FORCE``) and of the other
    contacts' weighted normals :math:`w_i n_i`, each times its :func:`hertz_share` q."""
    bx = by = bz = 0.0
    for i in range(count):
        q = hertz_share(tab[_row(at, i) + C_DEPTH], jump_out, margin)
        px, py, pz = _pushes(tab, at, i)
        bx += q * px
        by += q * py
        bz += q * pz
    bn = math.sqrt(bx * bx + by * by + bz * bz)
    return bx / bn, by / bn, bz / bn


@njit(cache=True)
def _ramp(x, margin):
    """r(x) = min(max(x / m, 0), 1)."""
    return min(max(x / margin, 0.0), 1.0)


@njit(cache=True)
def _entry_ramp(depth, closest, jump_out, margin):
    r"""A secondary contact's entry ramp at ``depth`` (m; module docstring, "Entry at the edge"):
    :math:`\min(r_d(\delta_i - \delta_{out}) / r_d(\delta_1 - \delta_{out}), 1)`, ``closest`` the closest
    contact's :math:`r_d(\delta_1 - \delta_{out})`."""
    e = _ramp(depth - jump_out, margin)
    return e / closest if e < closest else 1.0


@njit(cache=True)
def _depth_at(tab, r, ox, oy, oz):
    r"""The depth (m) of the contact in row ``r`` under the tip moved by (ox, oy, oz) m from the
    target: :math:`\delta_i - \Delta\cdot n_i`."""
    return tab[r + C_DEPTH] - (ox * tab[r + C_NX] + oy * tab[r + C_NX + 1] + oz * tab[r + C_NX + 2])


@njit(cache=True)
def _law_at(d, interacting, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold):
    """The Maugis-Dugdale answer ``(status, a, P)`` at depth ``d`` m, a = P = 0 where the solve failed or
    the tip is separated."""
    st, a, p = md_contact_hysteresis_kernel(d, interacting, depth_scale, radius_scale, load_scale, lam, t_fold,
                                            delta_fold)
    if st < 0 or st == SEPARATED:
        return st, 0.0, 0.0
    return st, a, p


@njit(cache=True)
def sum_loads_kernel(tab, at, count, nx, ny, nz, ox, oy, oz, interacting, jump_out, margin, depth_scale,
                     radius_scale, load_scale, lam, t_fold, delta_fold):
    r"""The summed contact force with the tip moved by :math:`\Delta` = (``ox, oy, oz``) m from the
    target (module docstring, "Entry at the edge"): contact i is :math:`\delta_i - \Delta\cdot n_i`
    deep and carries :math:`w_i\,e_i\,P(\delta_i - \Delta\cdot n_i)\,n_i`, the closest one
    :math:`P(\delta_1 - \Delta\cdot n_1)\,V_1` ("A hop inside one zone"), P the Maugis-Dugdale law
    (``MaugisDugdale.kernel_args``) under the tip's hysteresis state ``interacting``.

    Returns ``(fx, fy, fz, F.n, status, a, load, depth)``: the force (N), its part along the total
    normal n, and the closest contact's (row 0) answer at its depth (status, radius m, load N, depth m)."""
    d0 = _depth_at(tab, _row(at, 0), ox, oy, oz)
    e0 = _ramp(d0 - jump_out, margin)
    fx = fy = fz = 0.0
    st0 = SEPARATED
    a0 = p0 = 0.0
    for i in range(count):
        r = _row(at, i)
        if not tab[r + C_WEIGHT] > 0.0:
            continue
        d = d0 if i == 0 else _depth_at(tab, r, ox, oy, oz)
        st, a, p = _law_at(d, interacting, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold)
        ramp = 1.0
        if i == 0:  # the closest contact pushes along V_1 (its weight included)
            st0, a0, p0 = st, a, p
        else:
            ramp = _entry_ramp(d, e0, jump_out, margin)
        px, py, pz = _pushes(tab, at, i)
        fx += ramp * p * px
        fy += ramp * p * py
        fz += ramp * p * pz
    return fx, fy, fz, fx * nx + fy * ny + fz * nz, st0, a0, p0, d0


@njit(cache=True)
def coupled_lift_kernel(tab, at, count, nx, ny, nz, k_couple, interacting, start, jump_out, margin, depth_scale,
                        radius_scale, load_scale, lam, t_fold, delta_fold):
    r"""The lift :math:`\ell` (m) of the one rigid tip behind a virtual coupling of stiffness
    ``k_couple`` (N/m; ``inf``: none) along the total normal n, resting on all the contacts of
    ``tab``: the root of

    .. math:: g(\ell) = F_N(\ell)\cdot n - k_c\,\ell, \qquad F_N(\ell) = \sum_i w_i e_i P_i(\delta_i - \ell\, n\cdot n_i)\, n_i

    (:func:`sum_loads_kernel`), the several-contact form of
    :func:`~arsurf.contact.proxy.coupled_depth_kernel`'s :math:`P(\delta) = k_c(\delta_t - \delta)`:
    along n every contact is in series with the coupling, so the hand feels at most :math:`k_c`
    along n however many contacts carry the tip (sideways: module docstring). :math:`F_N\cdot n` falls as the tip lifts, so the root lies
    between 0 and :math:`F_N(0)\cdot n / k_c`; Newton's method from ``start`` (the previous
    tick's lift), bisection whenever a step leaves the bracket.

    Returns ``(lift, coupled, fx, fy, fz, F.n, status, a, load, depth)``: the lift, whether the
    coupling equation was solved (False, lift 0: no coupling, or the closest contact separated at
    the target: the tip is at the target) and :func:`sum_loads_kernel`'s answer at that lift."""
    fx, fy, fz, g0, st, a, p, d = sum_loads_kernel(tab, at, count, nx, ny, nz, 0.0, 0.0, 0.0, interacting, jump_out,
                                                   margin, depth_scale, radius_scale, load_scale, lam, t_fold,
                                                   delta_fold)
    if not (k_couple < math.inf) or st < 0 or st == SEPARATED:
        return 0.0, False, fx, fy, fz, g0, st, a, p, d
    top = g0 / k_couple
    lo, hi = min(0.0, top), max(0.0, top)
    lift = start if (math.isfinite(start) and lo < start < hi) else 0.5 * (lo + hi)
    h = 1e-4 * depth_scale
    tol = 1e-9 * load_scale
    for _ in range(_MAX_LIFT_ITER):
        fx, fy, fz, fn, st, a, p, d = sum_loads_kernel(tab, at, count, nx, ny, nz, lift * nx, lift * ny, lift * nz,
                                                       True, jump_out, margin, depth_scale, radius_scale, load_scale,
                                                       lam, t_fold, delta_fold)
        g = fn - k_couple * lift
        if abs(g) <= tol or hi - lo <= 1e-9 * depth_scale:
            return lift, st != SEPARATED, fx, fy, fz, fn, st, a, p, d
        if g > 0.0:
            lo = lift
        else:
            hi = lift
        f2 = sum_loads_kernel(tab, at, count, nx, ny, nz, (lift + h) * nx, (lift + h) * ny, (lift + h) * nz, True,
                              jump_out, margin, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold)[3]
        slope = (f2 - fn) / h - k_couple
        step = lift - g / slope if slope < 0.0 else math.nan
        lift = step if lo < step < hi else 0.5 * (lo + hi)
    fx, fy, fz, fn, st, a, p, d = sum_loads_kernel(tab, at, count, nx, ny, nz, lift * nx, lift * ny, lift * nz, True,
                                                   jump_out, margin, depth_scale, radius_scale, load_scale, lam,
                                                   t_fold, delta_fold)
    return lift, st != SEPARATED, fx, fy, fz, fn, st, a, p, d


@njit(cache=True)
def _sideways_stiffness(tab, at, count, ox, oy, oz, t1x, t1y, t1z, t2x, t2y, t2z, jump_out, margin, depth_scale,
                        radius_scale, load_scale, lam, t_fold, delta_fold):
    r"""The summed contacts' stiffness in the plane of (t1, t2) at the tip's offset (``ox, oy, oz``)
    m: the symmetric part of :math:`K = -\partial F/\partial\Delta = \sum_i k_i\,p_i m_i^T` read in
    that basis, ``(K11, K12, K22)`` N/m; :math:`k_i = (P(\delta_i + m) - P(\delta_i))/m` the law's
    secant stiffness over one weight margin ``margin`` m at contact i's depth (its weight and entry
    ramp held): the tangent stiffness :math:`2E^*a` grows as the square root of the depth where a
    contact's radius leaves 0, and a force that reads it turned there within 0.015 nm (0.2 nN in a
    valley narrower than the tip); :math:`p_i` the force it pushes per unit load, :math:`m_i` the
    direction along which its depth changes (:func:`sum_loads_kernel`)."""
    h = margin
    e0 = _ramp(_depth_at(tab, _row(at, 0), ox, oy, oz) - jump_out, margin)
    k11 = k12 = k22 = 0.0
    for i in range(count):
        r = _row(at, i)
        if not tab[r + C_WEIGHT] > 0.0:
            continue
        mx, my, mz = tab[r + C_NX], tab[r + C_NX + 1], tab[r + C_NX + 2]
        px, py, pz = _pushes(tab, at, i)
        d = _depth_at(tab, r, ox, oy, oz)
        e = 1.0 if i == 0 else _entry_ramp(d, e0, jump_out, margin)
        p = _law_at(d, True, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold)[2]
        p2 = _law_at(d + h, True, depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold)[2]
        k = e * (p2 - p) / h
        p1, p2_, m1, m2 = (px * t1x + py * t1y + pz * t1z, px * t2x + py * t2y + pz * t2z,
                           mx * t1x + my * t1y + mz * t1z, mx * t2x + my * t2y + mz * t2z)
        k11 += k * p1 * m1
        k22 += k * p2_ * m2
        k12 += 0.5 * k * (p1 * m2 + p2_ * m1)
    return k11, k12, k22


@njit(cache=True)
def coupled_offset_kernel(tab, at, count, nx, ny, nz, k_couple, lift, fx, fy, fz, jump_out, margin, depth_scale,
                          radius_scale, load_scale, lam, t_fold, delta_fold):
    r"""The one rigid tip behind a virtual coupling of stiffness ``k_couple`` (N/m) sideways too.
    :func:`coupled_lift_kernel` balances the coupling against the summed force (``fx, fy, fz`` N
    there) along the total normal n (lift ``lift`` m); the part r of the force off n is then passed
    through the coupling
    in series with the contacts' sideways stiffness: the tip moves by
    :math:`s = (k_c I + K_t)^{-1} r` in the plane normal to n, :math:`K_t` the symmetric part of
    the summed stiffness (:func:`_sideways_stiffness`) in that plane, its eigenvalues held >= 0, and
    the hand gets :math:`k_c s` there - one Newton step of the balance :math:`k_c\Delta = F_N(\Delta)`
    from the lift, continuous in its inputs. Sideways the walls of a valley then push the hand
    back with about :math:`k_c` (module docstring, "One tip behind the coupling").

    Returns ``(ox, oy, oz, fx, fy, fz)``: the tip's offset from the target (m) and the force (N)."""
    ox, oy, oz = lift * nx, lift * ny, lift * nz
    fn = fx * nx + fy * ny + fz * nz
    rx, ry, rz = fx - fn * nx, fy - fn * ny, fz - fn * nz
    # an orthonormal basis (t1, t2) of the plane normal to n
    if abs(nx) < 0.9:
        t1x, t1y, t1z = 0.0, nz, -ny
    else:
        t1x, t1y, t1z = -nz, 0.0, nx
    tn = math.sqrt(t1x * t1x + t1y * t1y + t1z * t1z)
    t1x, t1y, t1z = t1x / tn, t1y / tn, t1z / tn
    t2x, t2y, t2z = ny * t1z - nz * t1y, nz * t1x - nx * t1z, nx * t1y - ny * t1x
    a11, a12, a22 = _sideways_stiffness(tab, at, count, ox, oy, oz, t1x, t1y, t1z, t2x, t2y, t2z, jump_out, margin,
                                        depth_scale, radius_scale, load_scale, lam, t_fold, delta_fold)
    # eigenvalues held >= 0 (a softening contact adds no sideways spring)
    mean = 0.5 * (a11 + a22)
    rad = math.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
    l1, l2 = max(mean + rad, 0.0), max(mean - rad, 0.0)
    if rad > 0.0:
        c = math.sqrt(0.5 * (1.0 + 0.5 * (a11 - a22) / rad))  # the first eigenvector (c, s) in (t1, t2)
        sn = math.sqrt(max(0.5 * (1.0 - 0.5 * (a11 - a22) / rad), 0.0))
        if a12 < 0.0:
            sn = -sn
    else:
        c, sn = 1.0, 0.0
    r1 = rx * t1x + ry * t1y + rz * t1z
    r2 = rx * t2x + ry * t2y + rz * t2z
    e1 = (c * r1 + sn * r2) / (k_couple + l1)  # the move along each eigenvector
    e2 = (-sn * r1 + c * r2) / (k_couple + l2)
    s1, s2 = c * e1 - sn * e2, sn * e1 + c * e2
    sx, sy, sz = s1 * t1x + s2 * t2x, s1 * t1y + s2 * t2y, s1 * t1z + s2 * t2z
    return ox + sx, oy + sy, oz + sz, fn * nx + k_couple * sx, fn * ny + k_couple * sy, fn * nz + k_couple * sz
