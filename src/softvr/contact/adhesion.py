"""Implicit adhesion with bonding and debonding (thesis ch. 4, after Raous et al. [RCC99]).

Adhesive contact obeys (eq. 4.10) ``0 <= -p + C beta^2 g  _|_  g >= 0``: under traction p
the interface opens a gap g and pulls back like a spring of stiffness ``C beta^2`` per unit
area, with ``beta`` in [0, 1] the adhesion intensity of the contact. The constraint is
implicit in the contact solver (eqs. 4.13-4.16): in each projected Gauss-Seidel update of a
contact with local area A, the lower bound of its normal impulse becomes

    lambda_n >= min(k d_bar / (1 + k B_ii), 0),   k = dt^2 A C beta^2          (eq. 4.16)

and its tangential impulses may reach the same implicit adhesive bound in either direction,
or the Coulomb bound, whichever holds more (steps 4-8 of 4.3.2). This module holds the
material parameters, the per-contact intensities and tangential slips; the projection itself
is in :mod:`softvr.contact._pgs_kernels`.

Tangential adhesion is a spring on the slip (extending eqs. 4.10, 4.12 and 4.16 to the tangent
plane as in [RCC99]). The thesis' tangential "gap" is the slip of one step, ``dt v_t``, so its
bound is a damper: under any sideways force above friction a bonded contact creeps, step after
step. Here every bonded contact keeps its slip since bonding, ``u`` [m] (world, in the tangent
plane; :attr:`AdhesionState.slip`), and the tangential gap of the step is the slip at its end,
``u + dt v_t``. The traction law ``p_t = -C beta^2 (u + dt v_t)`` (eq. 4.10 along a tangent t)
makes the tangent row's target ``-u . t / dt`` (:func:`softvr.contact.solve_contacts`), and
the bound of eq. 4.16 on that row, ``k d_bar / (1 + k B_tt)`` with ``d_bar`` including the
target, is then the impulse of the stretched spring ``dt A C beta^2 (u + dt v_t) . t``. A force
F below the limit held by bonded contacts therefore stretches them by ``F / sum(A C beta^2)``
and no further. Within the Coulomb bound (the larger of the two holds, steps 6-7 of 4.3.2)
the contact returns to where it bonded.

Past its limit a bond under normal traction tears and one under compression slides, after the
asymmetry of 4.3.3 (compression bonds, traction debonds):

* under normal traction the stretch is kept whole, as in [RCC99]: a bond loaded sideways past
  ``p*`` stretches on, stores more than W and debonds by eq. 4.12 (an overhanging cloth, a
  block pulled sideways);
* under compression (a normal impulse > 0 in the step) the stored stretch is capped at the one
  whose traction is the debonding limit, ``|u| <= p*(beta) / (C beta^2) = sqrt(W / (C
  beta))``: the contact slides at its limit, plus the thesis' one-step term ``C beta^2 dt
  |v_t|``, its anchor dragged along as if it bonded anew on the surface it is pressed onto (a
  new contact bonds at ``beta0`` on touch). Sliding faster than the spring can follow still
  debonds by the end-of-step stretch, at a rate that grows with the speed: the thesis' own
  tangential debonding. Without the cap a contact that lands sliding (a cloth slapping onto a
  wall) stretches its spring millimetres within a few steps, ``C g^2 beta`` hundreds of times
  W, and every bond gives at once.

A contact whose bond has given (beta = 0) or that is forgotten loses its slip: bonding again
anchors it anew.

After each step (4.3.3) the intensity evolves by explicit Euler, from the tractions
``p = -lambda / (dt A)`` of the solve and the gap the traction law gives, ``g = p / (C beta^2)``:

* bonding under normal compression c (eq. 4.11): ``beta_dot = r max(c - beta p0, 0)``;
* debonding (eq. 4.12): ``beta_dot = min(W - C g^2 beta, 0) / eta``, with p the norm of the
  normal and tangential adhesive tractions under normal traction, of the tangential one alone
  under compression (where bonding acts as well). The tangential adhesive traction is the
  spring's, ``C beta^2 |u + dt v_t|`` from the slip at the end of the step (before the cap):
  the part of the tangential impulse that the PGS bound ``max(mu lambda_n, spring)`` lets
  adhesion carry. Where the spring bound holds, it is all of the tangential impulse; where the
  Coulomb bound holds more, friction carries the rest; inside both, the contact is back at its
  anchor and the spring carries nothing;
* a contact whose gap exceeds ``debond_gap`` is fully debonded and forgotten (touching again
  later makes a new contact at ``beta0``); one that debonds to 0 while still close stays at 0;
* a contact without area (a collision point with no surface around it) does not adhere: it
  stands for no interface, and a traction ``lambda / (dt A)`` would be infinite.

Debonding starts once ``C g^2 beta = W``, that is at the traction ``p* = sqrt(W C beta^3)``.

Combining two materials: C, W, r and p0 are the geometric means of the two sides (so a
non-adhesive side, C = 0, makes the pair non-adhesive), eta the geometric mean, beta0 and
``debond_gap`` the smaller of the two. A static plane or mesh takes the ``Adhesion`` given to
:meth:`softvr.Scene.add_plane` / ``add_mesh``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from softvr.collision.contacts import ContactKind, unpack_keys
from softvr.contact._adhesion_kernels import yields_patch
from softvr.errors import InputError

__all__ = ["Adhesion", "AdhesionState", "combine"]


@dataclass(frozen=True)
class Adhesion:
    """Adhesion parameters of a material (thesis 4.2).

    Attributes
    ----------
    stiffness : float [N/m^3]
        Adhesion stiffness C: traction per unit gap at full intensity (thesis: 1e6-1e8).
    max_energy : float [J/m^2]
        Maximum adhesion energy W; debonding starts once ``C g^2 beta`` exceeds it.
    viscosity : float [J s/m^2]
        Debonding viscosity eta > 0: larger debonds more slowly.
    bonding_rate : float [1/(Pa s)]
        Bonding rate r under compression.
    saturation : float [Pa]
        Compression p0 at which bonding saturates (beta stops growing at c = beta p0).
    initial : float
        Intensity beta0 in [0, 1] of a new contact.
    debond_gap : float [m]
        Gap beyond which a contact is fully debonded.
    """

    stiffness: float
    max_energy: float
    viscosity: float
    bonding_rate: float = 0.0
    saturation: float = 1.0
    initial: float = 1.0
    debond_gap: float = 0.005

    def __post_init__(self) -> None:
        checks = (
            ("stiffness", self.stiffness >= 0, "a finite value >= 0 [N/m^3]"),
            ("max_energy", self.max_energy >= 0, "a finite value >= 0 [J/m^2]"),
            ("viscosity", self.viscosity > 0, "a finite value > 0 [J s/m^2] (eta = 0 would debond instantly)"),
            ("bonding_rate", self.bonding_rate >= 0, "a finite value >= 0 [1/(Pa s)]"),
            ("saturation", self.saturation > 0, "a finite value > 0 [Pa]"),
            ("initial", 0.0 <= self.initial <= 1.0, "an intensity in [0, 1]"),
            ("debond_gap", self.debond_gap > 0, "a finite gap > 0 [m]"),
        )
        for name, ok, expected in checks:
            value = getattr(self, name)
            if not (ok and math.isfinite(value)):
                raise InputError(f"Adhesion.{name}", expected, repr(value))

    def traction_limit(self, beta: float = 1.0) -> float:
        """Traction [Pa] at which debonding starts for intensity ``beta``: sqrt(W C beta^3)."""
        return math.sqrt(self.max_energy * self.stiffness * beta**3)


def combine(a: Adhesion | None, b: Adhesion | None) -> Adhesion | None:
    """The adhesion of a contact between materials ``a`` and ``b`` (module docstring); None
    (no adhesion) when either side has none."""
    if a is None or b is None:
        return None
    return Adhesion(stiffness=math.sqrt(a.stiffness * b.stiffness), max_energy=math.sqrt(a.max_energy * b.max_energy),
                    viscosity=math.sqrt(a.viscosity * b.viscosity),
                    bonding_rate=math.sqrt(a.bonding_rate * b.bonding_rate),
                    saturation=math.sqrt(a.saturation * b.saturation), initial=min(a.initial, b.initial),
                    debond_gap=min(a.debond_gap, b.debond_gap))


class AdhesionState:
    """Adhesion intensities of the tracked contacts, by stable contact id.

    A contact with area is tracked from the step it first touches (normal impulse > 0 or gap
    <= 0 at the end of the step), starting at ``beta0``, until it is no longer detected or its
    gap exceeds ``debond_gap``; only tracked contacts adhere.

    Attributes
    ----------
    intensity : dict[int, float]
        beta of every tracked adhesive contact.
    slip : dict[int, ndarray]
        Tangential slip ``u`` [3] [m] (world) of every bonded contact since it bonded, less
        what it slid at its limit while pressed: the stretch of its tangential adhesive
        spring. The contact solver reads it and leaves the slip at the end of the step
        (``slip=`` of :func:`softvr.contact.solve_contacts`); :meth:`evolve` debonds by it,
        caps it and forgets it with the bond.
    """

    def __init__(self):
        self.intensity: dict[int, float] = {}
        self.slip: dict[int, np.ndarray] = {}

    def stiffness(self, contacts, adhesion: Adhesion | None) -> np.ndarray:
        """``A C beta^2`` [N/m] per contact of one contact set: the implicit adhesive stiffness
        the solver uses (``k = dt^2 A C beta^2``, eq. 4.16). 0 without adhesion or area, and for
        contacts that have not touched yet: a speculative contact (a gap within the margin)
        must not pull the surfaces together from a distance. Its tangential slips are in
        :attr:`slip`."""
        if adhesion is None or not len(contacts):
            return np.zeros(len(contacts))
        beta = np.array([self.intensity.get(int(i), 0.0) for i in contacts.ids])
        return contacts.area * adhesion.stiffness * beta**2

    def stiffnesses(self, contact_sets, adhesions) -> list[np.ndarray]:
        """:meth:`stiffness` of each contact set of a step (``adhesions``: one
        :class:`Adhesion` or None per set), a face-to-face patch between two bodies bonding one
        way: where body a's vertices on b's triangles and b's on a's both bond, the way that
        :func:`~softvr.contact._adhesion_kernels.yields_patch` picks (the node arrays' rule) has
        stiffness 0 [N/m]; its contacts keep their intensities and may take over."""
        out = [self.stiffness(c, a) for c, a in zip(contact_sets, adhesions)]
        tally: dict[tuple[int, int], tuple[int, float]] = {}
        ways = []  # (set, its ordered body pair) of the vertex-triangle sets
        for n, c in enumerate(contact_sets):
            if len(c) and c.b is not None and unpack_keys(c.ids[:1])["kind"][0] == ContactKind.VERTEX_TRIANGLE:
                pair = (c.a.body, c.b.body)
                bonded = out[n] > 0
                count, area = tally.get(pair, (0, 0.0))
                tally[pair] = (count + int(bonded.sum()), area + float(np.asarray(c.area)[bonded].sum()))
                ways.append((n, pair))
        for n, (a, b) in ways:
            (mine, mine_area), (theirs, theirs_area) = tally[(a, b)], tally.get((b, a), (0, 0.0))
            # A way the other does not bond keeps its own (and needs no call: ~0.3 ms each).
            if theirs and yields_patch(mine, theirs, wp.float64(mine_area), wp.float64(theirs_area), a, b):
                out[n] = np.zeros_like(out[n])
        return out

    def _slips(self, ids: np.ndarray) -> np.ndarray:
        """Stored slips [len(ids), 3] [m] of contacts ``ids``, 0 where none is stored."""
        return np.array([self.slip.get(int(i), (0.0, 0.0, 0.0)) for i in ids], float).reshape(-1, 3)

    def evolve(self, contact_sets, adhesions, impulses, gaps_after, dt: float) -> None:
        """Bonding / debonding of every adhesive contact after a step (thesis 4.3.3).

        Parameters
        ----------
        contact_sets : list of Contacts
        adhesions : list of Adhesion or None
            One per contact set.
        impulses : list of ndarray, each [contact_count, 3] [N s]
            (normal, tangent, binormal) impulses of the solve. The tangential adhesive
            tractions come from :attr:`slip` instead, as the solve left it (the slip at the end
            of the step); :meth:`evolve` then caps it at the limit stretch ``sqrt(W / (C
            beta))`` of the new intensity where the contact was pressed (module docstring).
        gaps_after : list of ndarray, each [contact_count] [m]
            Normal gap at the end of the step (full debond beyond ``debond_gap``).
        dt : float [s]
        """
        updated: dict[int, float] = {}
        slips: dict[int, np.ndarray] = {}
        for contacts, adhesion, lam, gap in zip(contact_sets, adhesions, impulses, gaps_after):
            if adhesion is None or not len(contacts):
                continue
            lam = np.asarray(lam, float)
            # A contact bonds from the step it first touches (pushed, or closed): at beta0.
            tracked = np.array([int(i) in self.intensity for i in contacts.ids], bool)
            touched = tracked | (lam[:, 0] > 0) | (gap <= 0)
            beta = np.array([self.intensity.get(int(i), adhesion.initial) for i in contacts.ids])
            # Tractions per unit area (normal > 0 under traction); a contact without area has
            # none and is not tracked (below).
            area = np.asarray(contacts.area, float)
            has_area = area > 0
            per_area = np.divide(1.0, dt * area, out=np.zeros_like(area), where=has_area)
            p = -lam * per_area[:, None]
            # The tangential traction adhesion carries: its spring's, from the slip the solver
            # left at the end of the step (friction carries the rest of the tangential impulse,
            # and debonds nothing). A contact not bonded in the solve has no spring.
            slip = self._slips(contacts.ids)
            tangential = adhesion.stiffness * beta**2 * np.linalg.norm(slip, axis=1)
            pulled = p[:, 0] > 0
            debond_p = np.where(pulled, np.hypot(p[:, 0], tangential), tangential)
            # C g^2 beta with the traction law's gap g = p / (C beta^2): p^2 / (C beta^3); no
            # adhesion (C beta = 0) stores no energy.
            held = adhesion.stiffness * beta**3
            energy = np.divide(debond_p**2, held, out=np.zeros_like(held), where=held > 0)
            rate = np.minimum(adhesion.max_energy - energy, 0.0) / adhesion.viscosity
            compression = np.where(pulled, 0.0, -p[:, 0])
            rate += adhesion.bonding_rate * np.maximum(compression - beta * adhesion.saturation, 0.0)
            beta = np.clip(np.nan_to_num(beta + dt * rate, nan=0.0), 0.0, 1.0)
            # Fully debonded past the gap threshold: forgotten, so that a later touch is a new
            # contact (starting at beta0). A contact debonded to 0 while still close stays at 0.
            keep = touched & has_area & (gap <= adhesion.debond_gap)
            updated.update(zip(contacts.ids[keep].tolist(), beta[keep].tolist()))
            # Past its limit a pressed bond slides: its anchor is dragged along so that the
            # stored stretch holds at most the limit traction p*(beta) of the new intensity. A
            # bond under traction keeps its whole stretch, and tears by it (module docstring).
            bonded = keep & (beta > 0) & np.any(slip != 0.0, axis=1)
            if bonded.any():
                limit = np.sqrt(adhesion.max_energy / (adhesion.stiffness * beta[bonded]))
                scale = np.minimum(1.0, limit / np.linalg.norm(slip[bonded], axis=1))
                scale = np.where(lam[bonded, 0] > 0, scale, 1.0)
                slips.update(zip(contacts.ids[bonded].tolist(), slip[bonded] * scale[:, None]))
        self.intensity = updated
        # A bond that gave (or a forgotten contact) loses its anchor: bonding again starts a
        # new, unstretched tangential spring.
        self.slip = slips
