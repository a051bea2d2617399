"""Compiled implicit adhesion (thesis ch. 4) shared by the array contact solves: the rigid
bodies' (:mod:`softvr.contact._rigid_pgs_kernels`) and the node arrays'
(:mod:`softvr.contact._node_jacobi_kernels`, :mod:`softvr.contact._node_adhesion_kernels`).

Each function is one piece of :func:`softvr.contact.solve_contacts` with adhesion and of
:meth:`softvr.contact.AdhesionState.evolve` (the model and its derivation are in
:mod:`softvr.contact.adhesion` and docs/adhesion.md): the pair's material, the adhesive
stiffness ``A C beta^2``, which way of a face-to-face patch bonds, the bound of eq. 4.16, and
the bonding / debonding of 4.3.3. (:func:`yields_patch` is the per-object path's too, called
from Python.)
"""

from __future__ import annotations

import warp as wp

# Columns of the material table (softvr.sim.model.ADHESION_COLUMNS).
C, W, ETA, RATE, P0, BETA0, DEBOND = 0, 1, 2, 3, 4, 5, 6


@wp.func
def combined(materials: wp.array2d(dtype=wp.float64), a: int, b: int, column: int) -> wp.float64:
    """A parameter of the pair's adhesion (:func:`softvr.contact.combine`): geometric mean, or
    the smaller of the two for beta0 and the debond gap. ``materials`` [m, 7]: rows of
    :data:`softvr.sim.model.ADHESION_COLUMNS` (SI)."""
    if column == BETA0 or column == DEBOND:
        return wp.min(materials[a, column], materials[b, column])
    return wp.sqrt(materials[a, column] * materials[b, column])


@wp.func
def bond_stiffness(materials: wp.array2d(dtype=wp.float64), a: int, b: int, area: wp.float64,
                   beta: wp.float64) -> wp.float64:
    """``A C beta^2`` [N/m] of a contact of area ``area`` [m^2] between materials ``a`` and
    ``b`` (-1: none) at intensity ``beta`` (< 0: not tracked): the solver's ``k = dt^2 A C
    beta^2`` (eq. 4.16) is this times dt^2. 0 without adhesion or before the contact touched
    (:meth:`softvr.contact.AdhesionState.stiffness`)."""
    k = wp.float64(0.0)
    if a >= 0 and b >= 0 and beta >= wp.float64(0.0):
        k = area * combined(materials, a, b, C) * beta * beta
    return k


@wp.func
def yields_patch(mine: int, theirs: int, mine_area: wp.float64, theirs_area: wp.float64, body: int,
                 other: int) -> bool:
    """Whether body ``body``'s vertex-triangle contacts on body ``other``'s triangles give up
    their bonds to the other way's (``other``'s vertices on ``body``'s triangles). Where two
    bodies bond face to face, contacts are made both ways and each way's vertex areas tile the
    patch: both together would bond it twice. The way with more bonded contacts (``mine`` /
    ``theirs``) adheres: the finer surface, whose vertex areas follow the patch's rim closer; on
    a tie the one with less bonded area (``mine_area`` / ``theirs_area`` [m^2]: the other's
    vertex areas overhang the patch, a larger face's vertices around a smaller one's edges),
    then the lower body index. Both paths' rule (:func:`softvr.contact._node_adhesion_kernels.share_patches`,
    :meth:`softvr.contact.AdhesionState.stiffnesses`); docs/adhesion.md."""
    if theirs == mine:
        return theirs_area < mine_area or (theirs_area == mine_area and other < body)
    return theirs > mine


@wp.func
def adhesive_bound(k: wp.float64, d_bar: wp.float64, diag: wp.float64) -> wp.float64:
    """Eq. 4.16: the implicit adhesive impulse ``k d_bar / (1 + k B_ii)`` [N s] of a row with
    ``k = dt^2 A C beta^2`` [kg], ``d_bar = B_ii lambda_i + target - row velocity`` [m/s] and
    response ``diag = B_ii`` [1/kg]."""
    return k * d_bar / (wp.float64(1.0) + k * diag)


@wp.func
def evolve_bond(materials: wp.array2d(dtype=wp.float64), ma: int, mb: int, beta_in: wp.float64,
                lam_n: wp.float64, gap_after: wp.float64, area: wp.float64, u: wp.vec3d, dt: wp.float64):
    """Bonding / debonding of one adhesive contact after a step (4.3.3, eqs. 4.11-4.12;
    :meth:`softvr.contact.AdhesionState.evolve`): from the intensity ``beta_in`` (< 0: not
    tracked), normal impulse ``lam_n`` [N s], linearized gap after the step ``gap_after`` [m],
    area ``area`` [m^2] and slip at the end of the step ``u`` [3] [m]. Returns the new
    intensity (-1 where the contact is forgotten: not touched, no area, or past the debond
    gap) and the slip it keeps [3] [m] (capped at the limit stretch where pressed, 0 when the
    bond gave)."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    beta_out = wp.float64(-1.0)
    u_out = wp.vec3d()
    stiff = combined(materials, ma, mb, C)
    energy_max = combined(materials, ma, mb, W)
    tracked = beta_in >= zero
    touched = tracked or lam_n > zero or gap_after <= zero
    beta = combined(materials, ma, mb, BETA0)
    if tracked:
        beta = beta_in
    per_area = zero
    if area > zero:
        per_area = one / (dt * area)
    p_n = -lam_n * per_area
    tangential = stiff * beta * beta * wp.length(u)
    debond_p = tangential
    if p_n > zero:
        debond_p = wp.sqrt(p_n * p_n + tangential * tangential)
    held = stiff * beta * beta * beta
    energy = zero
    if held > zero:
        energy = debond_p * debond_p / held
    rate = wp.min(energy_max - energy, zero) / combined(materials, ma, mb, ETA)
    compression = zero
    if p_n <= zero:
        compression = -p_n
    rate += combined(materials, ma, mb, RATE) * wp.max(compression - beta * combined(materials, ma, mb, P0), zero)
    beta = beta + dt * rate
    if not wp.isfinite(beta):
        beta = zero
    beta = wp.clamp(beta, zero, one)
    if touched and area > zero and gap_after <= combined(materials, ma, mb, DEBOND):
        beta_out = beta
        if beta > zero and wp.length(u) > zero:
            scale = one
            if lam_n > zero:
                scale = wp.min(one, wp.sqrt(energy_max / (stiff * beta)) / wp.length(u))
            u_out = u * scale
    return beta_out, u_out


@wp.func
def find_key(keys: wp.array(dtype=wp.uint64), count: int, key: wp.uint64) -> int:
    """Index of ``key`` in ascending ``keys[:count]``, -1 if absent."""
    low = int(0)
    high = count - 1
    while low <= high:
        mid = (low + high) // 2
        k = keys[mid]
        if k == key:
            return mid
        if k < key:
            low = mid + 1
        else:
            high = mid - 1
    return -1


@wp.func
def carry_sorted(i: int, key: wp.uint64, impulse: wp.vec3d, beta: wp.float64, u: wp.vec3d,
                 carried_key: wp.array(dtype=wp.uint64), carried_impulse: wp.array(dtype=wp.vec3d),
                 carried_intensity: wp.array(dtype=wp.float64), carried_slip: wp.array(dtype=wp.vec3d)):
    """Insert the step's contact ``i`` (its key, world impulse [N s], intensity, slip [m]) into
    the carried table whose rows ``[:i]`` hold the step's contacts before it, ascending by key
    (insertion sort: the detection order changes little from step to step)."""
    j = i - 1
    while j >= 0 and carried_key[j] > key:
        carried_key[j + 1] = carried_key[j]
        carried_impulse[j + 1] = carried_impulse[j]
        carried_intensity[j + 1] = carried_intensity[j]
        carried_slip[j + 1] = carried_slip[j]
        j -= 1
    carried_key[j + 1] = key
    carried_impulse[j + 1] = impulse
    carried_intensity[j + 1] = beta
    carried_slip[j + 1] = u
