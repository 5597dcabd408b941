"""The taut tether's quasi-static shape (docs/estimator.md, "The tether model"): what the rope of the
design does between the anchor and the balloon, given the pull it exerts on the balloon.

The paper's rope (Eq. 5) is straight with its whole weight on the balloon: in a 3 m/s wind it puts the
reference balloon's chord at 24 deg from the vertical. A real rope sags into a catenary and shares
its weight with the anchor: top tangent 9 deg, chord 15 deg, bottom 24 deg; its own cross-flow drag
bows it further downwind (chord 20 deg). The balloon leans with the top tangent, so a filter with the
paper's rope sees a tilt and a chord that cannot both be true, and settles on a wrong wind.

The filter keeps its taut model (a rod from the anchor to the attachment point, the tension along it,
tools/derive_model.py) and takes two of its parameters from the rope's real shape instead:

- the chord length ``L_c`` (< L: the sag and the bow shorten it), the rod's length;
- the weight the rod carries at the balloon, ``W_eff``: with the rod's tension along the chord,
  ``F_top = -T_c e + W_eff down``, the share of the rope's weight (and, through its bow, its drag)
  that makes the rod's pull equal the real rope's. (A flexible rope's drag acts on the rope, not at
  the balloon: the rod carries no drag term of its own.) Half the weight for a shallow sag
  (the parabola), more for a deep one, ``V_top - W / ln(V_top / V_bottom)`` in calm air.

The shape is integrated from the top down (``rope_chord``): the rope's force on what is above a cut
at arc length s, F(s), changes by its weight and the air's drag, dF/ds = -(w down + q), and the rope
runs along it, dX/ds = F / |F|. The rope is inextensible here: its stretch (EA is not in the design;
centimetres) is part of the radial row's tolerance. Pure functions over plain floats.
"""

from __future__ import annotations

import math

SHAPE_STEPS = 16  # midpoint steps along the rope: the chord to ~1e-4 of the length


def _drag(kq: float, wn: float, we: float, tn: float, te: float, td: float) -> tuple[float, float, float]:
    """Cross-flow drag per unit length on a rope element at rest along (tn, te, td): kq |u_n| u_n."""
    along = wn * tn + we * te
    un, ue, ud = wn - along * tn, we - along * te, -along * td
    s = kq * math.sqrt(un * un + ue * ue + ud * ud)
    return s * un, s * ue, s * ud


def rope_chord(
    fn: float, fe: float, fd: float, length_m: float, weight_n_m: float, drag_kg_m2: float, wn: float, we: float
) -> tuple[float, float, float]:
    """The chord from the anchor to the attachment point (NED, m) of an inextensible rope of this
    length and weight per metre whose pull on the balloon is (fn, fe, fd) N, in a uniform horizontal
    wind (wn, we) with cross-flow drag ``drag_kg_m2`` (1/2 rho Cn d) per metre; the rope at rest."""
    h = length_m / SHAPE_STEPS
    x = y = z = 0.0  # from the attachment point down the rope
    for _ in range(SHAPE_STEPS):
        m = math.sqrt(fn * fn + fe * fe + fd * fd)
        if m < 1e-9:
            break
        tn, te, td = fn / m, fe / m, fd / m
        qn, qe, qd = _drag(drag_kg_m2, wn, we, tn, te, td)
        # midpoint
        hn, he, hd = fn - 0.5 * h * qn, fe - 0.5 * h * qe, fd - 0.5 * h * (weight_n_m + qd)
        mm = math.sqrt(hn * hn + he * he + hd * hd)
        if mm < 1e-9:
            break
        tn, te, td = hn / mm, he / mm, hd / mm
        qn, qe, qd = _drag(drag_kg_m2, wn, we, tn, te, td)
        x += h * tn
        y += h * te
        z += h * td
        fn -= h * qn
        fe -= h * qe
        fd -= h * (weight_n_m + qd)
    return -x, -y, -z


def calm_weight_share(lift_n: float, rope_weight_n: float) -> float:
    """W_eff of a rope hanging in calm air (the limit of a vanishing horizontal pull): a deep
    catenary's V_top - W / ln(V_top / V_bottom); W / 2 for a light rope, W when the spare lift is gone."""
    v_top, v_bottom = lift_n, lift_n - rope_weight_n
    if rope_weight_n <= 1e-9 * max(lift_n, 1.0):
        return 0.5 * rope_weight_n
    if v_bottom <= 1e-6 * v_top:
        return rope_weight_n
    return v_top - rope_weight_n / math.log(v_top / v_bottom)


def effective_rod(fn: float, fe: float, fd: float, cn: float, ce: float, cd: float, rope_weight_n: float) -> float:
    """W_eff: the weight the rod model must carry at the balloon so that its pull, -T_c e + W_eff down,
    equals the rope's real pull F (e = the chord (cn, ce, cd) / |chord|). Bounded to [0, 1.5 W]:
    outside, the shape is not a rope's (a transient)."""
    ch = math.sqrt(cn * cn + ce * ce)
    if ch < 1e-6:
        return math.nan
    # the horizontal part of F along the chord's azimuth is the rod's: T_c e_h = -F_h
    t_over_c = -(fn * cn + fe * ce) / (ch * ch)  # T_c / |chord|
    w = fd + t_over_c * cd
    return min(max(w, 0.0), 1.5 * rope_weight_n)


class RopeShape:
    """The taut rod's two rope parameters, followed as the wind changes: the chord length and the
    weight the rod carries (both low-passed: parameters of the model, not states); ``rate_mps`` the
    chord's rate while a winch reels (aid_sources/winch.py; 0 without one)."""

    __slots__ = ("chord_m", "weight_n", "calm_weight_n", "rate_mps")

    def __init__(self, length_m: float, calm_weight_n: float) -> None:
        self.rate_mps = 0.0
        self.calm_weight_n = calm_weight_n
        self.chord_m = length_m
        self.weight_n = calm_weight_n


ANCHORED_NEWTON_STEPS = 12  # Newton steps from above the root: 1e-9 for heights 1e-3 .. 1e3 times the span


def anchored_rope_spread(weight_n_m: float, span_m: float, height_m: float) -> float:
    """How far apart (N) two honest pictures of the airborne rope's pull on a free balloon lie: hanging
    straight down, ``weight_n_m * height_m`` (the free ascent's model), or fed from the anchor, a catenary
    whose lowest point is the anchor (a rope coiled or reeled there and not yet lying on the ground
    below the balloon), ``w (s down + a towards the anchor)`` with its arc s and parameter a from
    h = a (cosh u - 1), x = a u at span x and height h. Their difference is w a (1, 1 - exp(-u)), as
    s - h = a (sinh u - cosh u + 1). 0 straight above the anchor."""
    if span_m <= 1e-6 * max(height_m, 1.0) or height_m <= 0.0:
        return 0.0
    rho = height_m / span_m  # < 1e6 here
    if rho < 1e-3:
        u = 2.0 * rho  # a flat rope: (cosh u - 1) / u = u / 2
    else:
        # (cosh u - 1) / u = rho: f(u) = cosh u - 1 - rho u is convex with f(0) = 0, f'(0) < 0, so Newton
        # from above its positive root falls onto it monotonically
        u = 1.0 + 4.0 * rho if rho <= 1.0 else math.log(4.0 * rho) + math.log(math.log(4.0 * rho) + 1.0) + 1.0
        for _ in range(ANCHORED_NEWTON_STEPS):
            ex = math.exp(u)
            u -= (0.5 * (ex + 1.0 / ex) - 1.0 - rho * u) / (0.5 * (ex - 1.0 / ex) - rho)
    return weight_n_m * span_m / u * math.hypot(1.0, 1.0 - math.exp(-u))
