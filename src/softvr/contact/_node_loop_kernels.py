"""The stop of a node solve's sweeps decided on the device (:meth:`NodeSolve.solve`'s loop as
one CUDA graph: ``wp.capture_while`` over the sweeps, ``wp.capture_if`` for the branches).

:meth:`softvr.contact.node_jacobi.NodeSolve.solve` checks its sweeps every two: it reads the
largest change back, estimates the error left (:func:`~softvr.contact.node_jacobi.tail_error`),
asks the contacts' residual when that is under the tolerance, and switches between Chebyshev and
plain sweeps. On a GPU each check would be a host round trip (a synchronization and the
decision in Python, tens of us: the candy pile's step makes ~35 of them). Here the same decisions
are taken by one device thread, two kernels a check, on the same numbers (float64, the host's
formulas in the host's order), so the host only launches the loop and reads its outcome once:

    begin         at a solve's start: the weights it starts on, the counters zeroed
    check_change  after two sweeps: the change recorded, the error's tail and the plateau
                  tested, whether the contacts' residual is wanted (``ctl[WANT]``)
    (residual)    where wanted, the host loop's ``_contacts_met`` launch
    check_stop    the stop, the switch to plain sweeps and back, the next two sweeps' kind
                  (``ctl[PLAIN]``) and whether there are any (``ctl[GO]``)

``ctl`` holds the loop's integers (slots below); ``changes`` / ``history`` the checked sweeps
and their largest changes [m/s] since the solve's start / the Chebyshev sweeps' (re)start, as
:class:`~softvr.contact.node_jacobi._Changes` holds them.
"""

import warp as wp

# Slots of ``ctl`` [CTL_SLOTS] int32. GO, PLAIN, WANT and WOKEN are the loop's and branches'
# conditions (wp.capture_while / capture_if read a one-element view of each).
GO = wp.constant(0)
K = wp.constant(1)
RESTART = wp.constant(2)
PLAIN_FROM = wp.constant(3)
PLAIN_UNTIL = wp.constant(4)
NARROW = wp.constant(5)
PLAIN = wp.constant(6)
PLAIN_SWEEPS = wp.constant(7)
PLATEAUED = wp.constant(8)
N_CHANGES = wp.constant(9)
N_HISTORY = wp.constant(10)
WANT = wp.constant(11)
WOKEN = wp.constant(12)
TAIL_OK = wp.constant(13)
PLATEAU = wp.constant(14)
ENDED = wp.constant(15)  # the change was NaN: the loop ends without a stop
STARTED_NARROW = wp.constant(16)
RETRYING_NOW = wp.constant(17)  # whether this solve's start on the narrower weights is a retry
WAKES = wp.constant(18)  # Gauss-Seidel checks that found a sleeping contact woken (NodeSolve.wakes)
# Carried from solve to solve (NodeSolve.start_narrow and its retry counters).
START_NARROW = wp.constant(19)
RETRYING = wp.constant(20)
RETRY = wp.constant(21)
UNTIL_RETRY = wp.constant(22)
# [3] one-hot: the buffer (sweeps modulo 3) holding the solved velocities, set when the loop ends,
# so that what follows the solve can choose its launches on the device (NodeSolve.buffer_flags).
BUFFER = wp.constant(23)
CTL_SLOTS = 26

_INF = wp.constant(wp.float64(float("inf")))


@wp.func
def _largest(sweeps: wp.array(dtype=wp.int32), values: wp.array(dtype=wp.float64), n: int, after: int,
             upto: int) -> wp.float64:
    """The largest of ``values[:n]`` of the sweeps ``j``, ``after < j <= upto`` (0 if none;
    ``sweeps`` ascending): :func:`softvr.contact.node_jacobi._largest`."""
    best = wp.float64(0.0)
    i = n - 1
    while i >= 0:
        if sweeps[i] <= after:
            break
        if sweeps[i] <= upto:
            best = wp.max(best, values[i])
        i = i - 1
    return best


@wp.func
def _observed_rate(sweeps: wp.array(dtype=wp.int32), values: wp.array(dtype=wp.float64), n: int, k: int,
                   window: int) -> wp.float64:
    """:func:`softvr.contact.node_jacobi.observed_rate`."""
    recent = _largest(sweeps, values, n, k - window, k)
    before = _largest(sweeps, values, n, k - 2 * window, k - window)
    if recent <= wp.float64(0.0):
        return wp.float64(0.0)
    if before > wp.float64(0.0):
        return wp.pow(recent / before, wp.float64(1.0) / wp.float64(window))
    return _INF


@wp.func
def _tail_error(sweeps: wp.array(dtype=wp.int32), values: wp.array(dtype=wp.float64), n: int, floor: wp.float64,
                window: int, tail_checks: int) -> wp.float64:
    """:func:`softvr.contact.node_jacobi.tail_error` (``window`` 0: None)."""
    k = sweeps[n - 1]
    rate = floor
    if window > 0 and k >= 2 * window:
        rate = wp.max(floor, _observed_rate(sweeps, values, n, k, window))
    if rate >= wp.float64(1.0):
        return _INF
    first = wp.max(n - tail_checks, 0)
    lead = values[first] * wp.pow(rate, wp.float64(k - sweeps[first]))
    for j in range(first + 1, n):
        lead = wp.max(lead, values[j] * wp.pow(rate, wp.float64(k - sweeps[j])))
    return lead * rate / (wp.float64(1.0) - rate)


@wp.func
def _window_test(sweeps: wp.array(dtype=wp.int32), values: wp.array(dtype=wp.float64), n: int, k: int,
                 window: int) -> wp.vec2d:
    """The largest change of the sweeps ``(k - window, k]`` and of ``(k - 2 window, k - window]``."""
    return wp.vec2d(_largest(sweeps, values, n, k - window, k), _largest(sweeps, values, n, k - 2 * window, k - window))


@wp.func
def _copy_weights(source: wp.array(dtype=wp.float64), weights: wp.array(dtype=wp.float64)):
    for i in range(weights.shape[0]):
        weights[i] = source[i]


@wp.kernel(enable_backward=False)
def begin(ctl: wp.array(dtype=wp.int32), cap: wp.array(dtype=wp.int32), first_weights: wp.array(dtype=wp.float64),
          bounds_weights: wp.array(dtype=wp.float64), weights: wp.array(dtype=wp.float64)):
    """A solve's start (one thread): the Chebyshev weights it starts on (the narrower ones where
    ``ctl[START_NARROW]``), whether that start is a retry, every counter of the loop zeroed;
    ``ctl[GO]`` whether it sweeps at all (``cap[0]``: the most sweeps), buffer 0's flag set."""
    narrow = ctl[START_NARROW]
    ctl[NARROW] = narrow
    ctl[STARTED_NARROW] = narrow
    ctl[RETRYING_NOW] = ctl[RETRYING]
    ctl[RETRYING] = 0
    if narrow != 0:
        _copy_weights(first_weights, weights)
    else:
        _copy_weights(bounds_weights, weights)
    for slot in range(K, START_NARROW):
        if slot != NARROW and slot != STARTED_NARROW and slot != RETRYING_NOW:
            ctl[slot] = 0
    ctl[GO] = wp.where(cap[0] > 0, 1, 0)
    for r in range(3):  # no sweeps: the start's buffer
        ctl[BUFFER + r] = wp.where(r == 0, 1, 0)


@wp.kernel(enable_backward=False)
def check_change(ctl: wp.array(dtype=wp.int32), woken: wp.array(dtype=wp.int32), stats: wp.array(dtype=wp.float64),
                 tolerance: wp.array(dtype=wp.float64), floors: wp.array2d(dtype=wp.float64), rho: wp.float64,
                 observed_window: int, tail_checks: int, window: int, cap: wp.array(dtype=wp.int32),
                 change_sweeps: wp.array(dtype=wp.int32), change_values: wp.array(dtype=wp.float64),
                 history_sweeps: wp.array(dtype=wp.int32), history_values: wp.array(dtype=wp.float64)):
    """The first half of a check after two sweeps (one thread; :meth:`NodeSolve.solve`'s check
    up to its ``_contacts_met`` calls): the sweep count ``k`` advanced; a woken Gauss-Seidel
    contact (``woken[0]``) makes the check a restart; else the largest change ``stats[0]``
    [m/s] recorded (NaN: the loop ends), the error's geometric tail against ``tolerance[0]``
    [m/s] (``floors[0 or 1, k - restart - 1]`` the Chebyshev floor on the narrower or the
    bounds' weights, ``rho`` on plain sweeps; ``observed_window`` 0 where the observed rate is
    not taken) and, on Chebyshev sweeps, the plateau over ``window`` sweeps. ``ctl[WANT]``:
    whether the contacts' residual is needed (a stop to confirm, or the loop's last check: ``k``
    at ``cap[0]``, the most sweeps)."""
    k = ctl[K] + 2
    ctl[K] = k
    plain = ctl[PLAIN]
    ctl[PLAIN_SWEEPS] = ctl[PLAIN_SWEEPS] + 2 * plain
    ctl[TAIL_OK] = 0
    ctl[PLATEAU] = 0
    last = wp.where(k >= cap[0], 1, 0)
    if woken[0] != 0:
        ctl[WOKEN] = 1
        ctl[WAKES] = ctl[WAKES] + 1
        ctl[PLAIN_UNTIL] = k
        ctl[WANT] = last
        return
    ctl[WOKEN] = 0
    change = stats[0]
    if not wp.isfinite(change):
        ctl[ENDED] = 1
        ctl[WANT] = 1
        return
    n = ctl[N_CHANGES]
    change_sweeps[n] = k
    change_values[n] = change
    n = n + 1
    ctl[N_CHANGES] = n
    restart = ctl[RESTART]
    floor = rho
    if plain == 0:
        floor = floors[wp.where(ctl[NARROW] != 0, 0, 1), k - restart - 1]
    tol = tolerance[0]
    tail_ok = wp.where(_tail_error(change_sweeps, change_values, n, floor, observed_window, tail_checks) <= tol, 1, 0)
    plateau = 0
    if plain == 0:
        h = ctl[N_HISTORY]
        history_sweeps[h] = k - restart
        history_values[h] = change
        h = h + 1
        ctl[N_HISTORY] = h
        since = k - restart
        if since >= 2 * window:
            pair = _window_test(history_sweeps, history_values, h, since, window)
            if pair[0] <= tol and pair[0] > wp.float64(0.5) * pair[1]:
                plateau = 1
    ctl[TAIL_OK] = tail_ok
    ctl[PLATEAU] = plateau
    ctl[WANT] = wp.where(tail_ok != 0 or plateau != 0 or last != 0, 1, 0)


@wp.kernel(enable_backward=False)
def check_stop(ctl: wp.array(dtype=wp.int32), stats: wp.array(dtype=wp.float64), tolerance: wp.array(dtype=wp.float64),
               rate: wp.float64, observed_window: int, switch_sweeps: int, switch_after: int, window: int,
               narrow_retry_first: int, narrow_retry_most: int, cap: wp.array(dtype=wp.int32), can_narrow: int,
               change_sweeps: wp.array(dtype=wp.int32), change_values: wp.array(dtype=wp.float64),
               history_sweeps: wp.array(dtype=wp.int32), history_values: wp.array(dtype=wp.float64),
               bounds_weights: wp.array(dtype=wp.float64), weights: wp.array(dtype=wp.float64),
               sweep: wp.array(dtype=wp.int32)):
    """The second half of a check (one thread): with the contacts' residual in ``stats[1:3]``
    [m/s] where ``ctl[WANT]``, the stop (the tail under ``tolerance[0]`` [m/s], or a plateau,
    with every contact meeting eq. 5.5), else on plain sweeps their early end (contracting
    slower than ``rate``, where ``observed_window`` > 0), on Chebyshev sweeps the switch to a
    window of plain sweeps where the narrower weights slowed or the sweeps stalled (and the next
    solve's start, ``can_narrow`` where there are narrower weights), then the next two sweeps:
    a restart of the Chebyshev weights (``sweep[0]`` zeroed) where a plain window ends,
    ``ctl[PLAIN]`` and ``ctl[GO]``. When the loop ends, the narrower weights' retry count and
    the solved velocities' buffer (``ctl[BUFFER + k % 3]``, the others 0)."""
    k = ctl[K]
    tol = tolerance[0]
    met = 0
    if ctl[WANT] != 0 and stats[1] <= tol and stats[2] <= tol:
        met = 1
    stop = 0
    n = ctl[N_CHANGES]
    if ctl[WOKEN] == 0 and ctl[ENDED] == 0:
        restart = ctl[RESTART]
        if ctl[TAIL_OK] != 0 and met != 0:
            stop = 1
        elif ctl[PLAIN] != 0:
            if observed_window > 0 and k - ctl[PLAIN_FROM] >= 2 * observed_window:
                if _observed_rate(change_sweeps, change_values, n, k, observed_window) > rate:
                    ctl[PLAIN_UNTIL] = k
        elif ctl[PLATEAU] != 0 and met != 0:
            ctl[PLATEAUED] = 1
            stop = 1
        else:
            since = k - restart
            narrow = ctl[NARROW]
            slowed = 0
            if narrow != 0 and since >= wp.max(switch_after, 2 * switch_sweeps):
                if _observed_rate(change_sweeps, change_values, n, k, switch_sweeps) > rate:
                    slowed = 1
            stalled = 0
            stall_window = wp.max(10, window // 2)
            h = ctl[N_HISTORY]
            if since >= 2 * stall_window and history_values[h - 1] > tol:
                pair = _window_test(history_sweeps, history_values, h, since, stall_window)
                if pair[0] > wp.float64(0.5) * pair[1]:
                    stalled = 1
            if slowed != 0 or stalled != 0:
                if can_narrow != 0:  # NodeSolve._next_start
                    start = 1
                    if slowed != 0:
                        fell = change_values[n - 1] <= change_values[0] * wp.pow(
                            rate, wp.float64(change_sweeps[n - 1] - change_sweeps[0]))
                        start = wp.where(fell, 1, 0)
                    ctl[START_NARROW] = start
                    if start == 0:
                        if ctl[RETRYING_NOW] != 0:
                            ctl[RETRY] = wp.min(2 * ctl[RETRY], narrow_retry_most)
                        else:
                            ctl[RETRY] = narrow_retry_first
                        ctl[UNTIL_RETRY] = ctl[RETRY]
                ctl[PLAIN_FROM] = k
                ctl[PLAIN_UNTIL] = k + window
                if narrow != 0:
                    _copy_weights(bounds_weights, weights)
                    ctl[NARROW] = 0
    if stop != 0 or ctl[ENDED] != 0 or k >= cap[0]:
        ctl[GO] = 0
        for r in range(3):
            ctl[BUFFER + r] = wp.where(r == k % 3, 1, 0)
        if can_narrow != 0 and ctl[STARTED_NARROW] == 0 and ctl[START_NARROW] == 0:
            ctl[UNTIL_RETRY] = ctl[UNTIL_RETRY] - 1
            again = wp.where(ctl[UNTIL_RETRY] <= 0, 1, 0)
            ctl[START_NARROW] = again
            ctl[RETRYING] = again
        return
    if k == ctl[PLAIN_UNTIL] and k > 0 and ctl[RESTART] < k:  # back to Chebyshev, from omega_1
        sweep[0] = 0
        ctl[RESTART] = k
        ctl[N_HISTORY] = 0
    ctl[PLAIN] = wp.where(k < ctl[PLAIN_UNTIL], 1, 0)
    ctl[GO] = 1
