r"""Sample means of a trajectory's specific force and angular rate, from verified fits.

A sensor sample is the mean of f^b and w_ib^b over its period (what a strapdown
algorithm reads as velocity and angle increments divided by the period). Evaluating the
exact kinematics (:func:`sensed`, the compiled twin of
:meth:`qfa_ros.model.trajectory.Trajectory.kinematics`: 8 trig functions, a square
root and six polynomial channels with two derivatives) costs ~0.15 us a point, so a
quadrature with two points a sample costs ~0.3 ms a sensor second at 1 kHz.
:class:`PiecewiseMeans` evaluates it far less often:

- **Fit.** Each polynomial piece of the trajectory is fitted, when a sample first
  reaches it, by Chebyshev interpolants of the six outputs on Chebyshev-Lobatto nodes of
  degree 2, 4, 8, 16, 32 (nested: each doubling reuses every point). A degree is
  accepted when the interpolant matches the exact outputs at the n points between its
  nodes (the next grid's new nodes) to :data:`FIT_FRACTION` of the tolerance, for each
  channel ``max(FORCE_TOLERANCE, RELATIVE_TOLERANCE |f|)`` [m/s^2] and
  ``max(RATE_TOLERANCE, RELATIVE_TOLERANCE |w|)`` [rad/s], ``|.|`` the channel's largest
  magnitude on the piece. A piece no degree 32 fits is cut in halves, recursively. The
  fits stay within each piece: the outputs are analytic inside a piece and kinked at its
  knots (C2 positions: f^b has a kink, w_ib^b a jump of its second derivative).
- **Integrate.** The mean over a sample is the exact integral of the fits over it,
  cut at the segment boundaries and the trajectory's ends (the body rests at the end
  poses outside), divided by its length. The mean of ``T_k`` over ``[y, x]`` comes from
  the divided differences ``D_k = (T_k(x) - T_k(y)) / (x - y)``, whose recurrence
  ``D_{k+1} = 2 x D_k + 2 T_k(y) - D_{k-1}`` has no cancellation however short the
  sample is on however long a segment (a 600 s dwell), unlike a difference of
  antiderivatives.
- **Fast path.** Over the samples lying wholly inside one segment the mean is itself a
  polynomial of the sample's start, ``q(u) = (E(u + h) - E(u)) / h`` in the segment's
  Chebyshev variable ``u`` (``E`` the antiderivative of the fit, ``h`` the sample's
  length in ``u``). Its Chebyshev coefficients come once per segment and sample period
  (cached) from the finite Taylor series ``sum_j h^(j-1) / j! E^(j)``, which has no
  cancellation when ``h n^2 <= 1`` (:data:`FAST_REACH`); each sample is then one
  Clenshaw evaluation of ``q`` (~10-20 ns for six channels, against ~60-80 ns for the
  integral). Samples straddling a segment boundary or the trajectory's ends, and
  segments too short in samples, keep the integral.

So the means are the exact means of the trajectory to the tolerance, which sits far
below what the sensors resolve: 1e-10 m/s^2 is 1 % of an accelerometer's ~1e-8 m/s^2
resolution, 1e-13 rad/s (or 1e-11 of the rate) is 1e-5 of the gyros' 1.5e-8 rad/s bias
instability, and 1e-11 relative is 1e-5 of a 1 ppm scale-factor error. The fits depend
on the piece alone, so the means do not depend on how the samples are cut into calls.

One cohesive module: the fits, their integrals and the mean polynomials share one
segment store that the compiled sample loop walks.
"""

import math

from numba import njit
import numpy as np

from qfa_ros.model import earth

FORCE_TOLERANCE = 1e-10
"""Absolute error bound of the mean specific force [m/s^2]."""
RATE_TOLERANCE = 1e-13
"""Absolute error bound of the mean angular rate [rad/s]."""
RELATIVE_TOLERANCE = 1e-11
"""Error bound relative to a channel's largest magnitude on a piece (the larger applies)."""
FIT_FRACTION = 0.25
"""The fits are held to this fraction of the bounds: margin for the errors between checks."""
MAX_DEGREE = 8
"""Highest Chebyshev degree tried before a segment is cut in halves (a sample's cost
grows with the degree; a fit's with the number of segments)."""
MAX_DEPTH = 30
"""Most halvings of a piece (the fit at this depth is kept whatever its error)."""
DIRECT_SAMPLES = 6.0
"""Pieces shorter than this many sample periods are integrated directly (see the top)."""
FAST_BLOCK = 64
"""Samples evaluated side by side by :func:`_fast`."""
FAST_REACH = 1.0
"""Samples inside a segment of degree n take its mean polynomial when their length is at most
``FAST_REACH / n^2`` of the segment's half length (see :func:`_mean_polynomial`)."""
_COSINES = np.cos(np.pi * np.arange(4 * MAX_DEGREE) / (2 * MAX_DEGREE))
"""cos(pi m / (2 MAX_DEGREE)), m < 4 MAX_DEGREE: every node, check and DCT cosine."""
_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(3)


@njit(cache=True, nogil=True, inline='always')
def _channel(c, i, ch, s, inside):
    """Return channel ``ch`` of piece ``i`` at local time ``s`` and its two derivatives."""
    value, first, second = c[0, i, ch], 0.0, 0.0
    for j in range(1, c.shape[0]):
        second = second * s + first
        first = first * s + value
        value = value * s + c[j, i, ch]
    return (value, first, 2.0 * second) if inside else (value, 0.0, 0.0)


@njit(cache=True, nogil=True)
def sensed(c, i, s, inside, out):
    """
    Write f^b [m/s^2] and w_ib^b [rad/s] of piece ``i`` at local time ``s`` [s] to ``out``.

    ``c`` holds the ``PPoly`` coefficients (k, m, 6) of the six channels; ``inside``
    False gives the body at rest at that pose (rates and accelerations zero). The
    compiled twin of :meth:`qfa_ros.model.trajectory.Trajectory.kinematics` (Groves 2013,
    eq. 5.54; the tests hold the two equal).
    """
    lat, dlat, ddlat = _channel(c, i, 0, s, inside)
    _, dlon, ddlon = _channel(c, i, 1, s, inside)
    h, dh, ddh = _channel(c, i, 2, s, inside)
    roll, droll, _ = _channel(c, i, 3, s, inside)
    pitch, dpitch, _ = _channel(c, i, 4, s, inside)
    yaw, dyaw, _ = _channel(c, i, 5, s, inside)
    sl, cl = math.sin(lat), math.cos(lat)
    e2 = earth.ECCENTRICITY_SQUARED
    a = earth.SEMI_MAJOR_AXIS
    s2 = sl * sl
    w2 = 1.0 - e2 * s2
    w = math.sqrt(w2)
    r_e = a / w
    r_n = r_e * (1.0 - e2) / w2
    dr_e = r_e * e2 * sl * cl / w2
    dr_n = 3.0 * r_n * e2 * sl * cl / w2
    ve = (r_e + h) * cl * dlon
    vn = (r_n + h) * dlat
    vu = dh
    ae = (dr_e * dlat + dh) * cl * dlon - (r_e + h) * sl * dlat * dlon + (r_e + h) * cl * ddlon
    an = (dr_n * dlat + dh) * dlat + (r_n + h) * ddlat
    au = ddh
    omega = earth.EARTH_RATE
    we, wn, wu = 0.0, omega * cl, omega * sl
    te, tn = -vn / (r_n + h), ve / (r_e + h)
    tu = tn * sl / cl
    ce, cn, cu = 2.0 * we + te, 2.0 * wn + tn, 2.0 * wu + tu
    gamma = earth.GAMMA_EQUATOR * (1.0 + earth.SOMIGLIANA_K * s2) / w
    gamma *= 1.0 - 2.0 / a * (1.0 + earth.FLATTENING + earth.GRAVITY_RATIO_M
                              - 2.0 * earth.FLATTENING * s2) * h + 3.0 * h * h / (a * a)
    fe = ae + cn * vu - cu * vn
    fn = an + cu * ve - ce * vu
    fu = au + ce * vn - cn * ve + gamma
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    # Columns of C_b^n = R_z R_y R_x: rows of C_n^b.
    b0 = (cy * cp, sy * cp, -sp)
    b1 = (cy * sp * sr - sy * cr, sy * sp * sr + cy * cr, cp * sr)
    b2 = (cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr)
    ie, inn, iu = we + te, wn + tn, wu + tu
    out[0] = b0[0] * fe + b0[1] * fn + b0[2] * fu
    out[1] = b1[0] * fe + b1[1] * fn + b1[2] * fu
    out[2] = b2[0] * fe + b2[1] * fn + b2[2] * fu
    out[3] = b0[0] * ie + b0[1] * inn + b0[2] * iu + droll - dyaw * sp
    out[4] = b1[0] * ie + b1[1] * inn + b1[2] * iu + dpitch * cr + dyaw * sr * cp
    out[5] = b2[0] * ie + b2[1] * inn + b2[2] * iu - dpitch * sr + dyaw * cr * cp


@njit(cache=True, nogil=True)
def _piece(x, t, right):
    """
    Return the piece of the breakpoints ``x`` that holds ``t``, within ``0 .. len(x) - 2``.

    ``np.searchsorted(x, t, 'right' if right else 'left') - 1``, clipped; a bisection of
    its own, which compiles in a fraction of the time numba's ``searchsorted`` takes.
    """
    low, high = 0, x.shape[0]
    while low < high:
        middle = (low + high) // 2
        if x[middle] < t or (right and x[middle] == t):
            low = middle + 1
        else:
            high = middle
    return min(max(low - 1, 0), x.shape[0] - 2)


@njit(cache=True, nogil=True)
def _clenshaw(coef, n, ch, u):
    """Return sum_k coef[k, ch] T_k(u), k = 0..n."""
    b1, b2 = 0.0, 0.0
    for k in range(n, 0, -1):
        b1, b2 = 2.0 * u * b1 - b2 + coef[k, ch], b1
    return u * b1 - b2 + coef[0, ch]


@njit(cache=True, nogil=True)
def _knot(c, x, k, knots, known, out):
    """
    Write the outputs at knot ``k`` to ``out``, from a two-entry cache of knot values.

    The value at a knot is always the same evaluation (piece ``k`` at its start, or the
    last piece at its end), so it does not matter whether it comes from the cache
    (``known`` the knots held in ``knots`` (2, 6), -1 none): neighbouring pieces share it.
    """
    for slot in range(2):
        if known[slot] == k:
            for ch in range(6):  # element by element: a row assignment compiles for seconds
                out[ch] = knots[slot, ch]
            return
    m = x.shape[0] - 1
    if k < m:
        sensed(c, k, 0.0, True, out)
    else:
        sensed(c, m - 1, x[m] - x[m - 1], True, out)
    slot = 0 if known[0] < known[1] else 1
    known[slot] = k
    for ch in range(6):
        knots[slot, ch] = out[ch]


@njit(cache=True, nogil=True)
def _fit(c, x, i, a, b, tolerance, coef, values, merged, checks, scale, knots, known):
    """
    Fit the outputs of piece ``i`` on ``[a, b]`` (Chebyshev, ``u = (2t - a - b)/(b - a)``).

    Write the coefficients (degree + 1, 6) to ``coef``; return the degree accepted, or
    -1 when degree :data:`MAX_DEGREE` misses the tolerance (``coef`` then holds that fit).
    ``tolerance`` is (absolute force, absolute rate, relative); ``values``, ``merged``
    (:data:`MAX_DEGREE` + 1, 6), ``checks`` (:data:`MAX_DEGREE`, 6) and ``scale`` (6,)
    are work space; ``knots`` and ``known`` the cache of :func:`_knot`.
    """
    mid, half = 0.5 * (a + b), 0.5 * (b - a)
    for ch in range(6):
        scale[ch] = 0.0
    n = 2
    for j in range(n + 1):
        t = mid + half * _COSINES[j * (2 * MAX_DEGREE // n)]
        if j == 0 and b == x[i + 1]:
            _knot(c, x, i + 1, knots, known, values[j])
        elif j == n and a == x[i]:
            _knot(c, x, i, knots, known, values[j])
        else:
            sensed(c, i, t - x[i], True, values[j])
    while True:
        # Interpolant through the Lobatto nodes u_j = cos(pi j / n) (a DCT-I).
        step = 2 * MAX_DEGREE // n
        for k in range(n + 1):
            sign = 1.0 if k % 2 == 0 else -1.0
            for ch in range(6):
                total = 0.5 * (values[0, ch] + sign * values[n, ch])
                for j in range(1, n):
                    total += values[j, ch] * _COSINES[(j * k * step) % (4 * MAX_DEGREE)]
                coef[k, ch] = total * (2.0 / n) * (0.5 if k == 0 or k == n else 1.0)
        for j in range(n):
            u = _COSINES[(2 * j + 1) * step // 2]
            sensed(c, i, mid + half * u - x[i], True, checks[j])
        for ch in range(6):
            for j in range(n + 1):
                scale[ch] = max(scale[ch], abs(values[j, ch]))
            for j in range(n):
                scale[ch] = max(scale[ch], abs(checks[j, ch]))
        good = True
        for ch in range(6):
            bound = FIT_FRACTION * max(tolerance[ch // 3], tolerance[2] * scale[ch])
            for j in range(n):
                u = _COSINES[(2 * j + 1) * step // 2]
                if abs(_clenshaw(coef, n, ch, u) - checks[j, ch]) > bound:
                    good = False
        if good:
            return n
        if 2 * n > MAX_DEGREE:
            return -1
        for ch in range(6):
            for j in range(n + 1):
                merged[2 * j, ch] = values[j, ch]
            for j in range(n):
                merged[2 * j + 1, ch] = checks[j, ch]
        values, merged = merged, values
        n *= 2


@njit(cache=True, nogil=True)
def _build(c, x, first, last, shortest, tolerance, piece_start, piece_count, bounds, degree,
           offset, coefs, used):
    """
    Fit pieces ``first..last`` not yet fitted; return False when the storage is full.

    Segments of a piece are stored consecutively, in time order, from
    ``piece_start[i]``; ``used`` holds the segments and coefficient rows in use. Pieces
    shorter than ``shortest`` [s] are marked for direct integration (count -1). A
    segment's rows are the Chebyshev coefficients ``e_1..e_{n+1}`` of the antiderivative
    of its fit (row 0 unused).
    """
    coef = np.empty((MAX_DEGREE + 1, 6))
    values, merged = np.empty((MAX_DEGREE + 1, 6)), np.empty((MAX_DEGREE + 1, 6))
    checks, scale = np.empty((MAX_DEGREE, 6)), np.empty(6)
    stack = np.empty((MAX_DEPTH + 2, 3))
    knots, known = np.empty((2, 6)), np.empty(2, np.int64)
    known[0], known[1] = -1, -1
    for i in range(first, last + 1):
        if piece_count[i] != 0:
            continue
        if x[i + 1] - x[i] < shortest:
            piece_count[i] = -1
            continue
        segments, rows = used[0], used[1]
        # Depth-first, right halves pushed first: segments come out in time order.
        stack[0, 0], stack[0, 1], stack[0, 2] = x[i], x[i + 1], 0.0
        top = 1
        while top > 0:
            top -= 1
            a, b, depth = stack[top, 0], stack[top, 1], stack[top, 2]
            n = _fit(c, x, i, a, b, tolerance, coef, values, merged, checks, scale, knots,
                     known)
            if n < 0 and depth < MAX_DEPTH:
                middle = 0.5 * (a + b)
                stack[top, 0], stack[top, 1], stack[top, 2] = middle, b, depth + 1
                stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = a, middle, depth + 1
                top += 2
                continue
            n = n if n >= 0 else MAX_DEGREE
            if segments >= bounds.shape[0] or rows + n + 2 > coefs.shape[0]:
                return False
            bounds[segments, 0], bounds[segments, 1] = a, b
            degree[segments], offset[segments] = n, rows
            for ch in range(6):
                coefs[rows, ch] = 0.0
                for j in range(1, n + 2):
                    left = coef[j - 1, ch] * (2.0 if j == 1 else 1.0)
                    right = coef[j + 1, ch] if j + 1 <= n else 0.0
                    coefs[rows + j, ch] = (left - right) / (2.0 * j)
            segments += 1
            rows += n + 2
        piece_start[i] = used[0]
        piece_count[i] = segments - used[0]
        used[0], used[1] = segments, rows
    return True


@njit(cache=True, nogil=True)
def _mean_polynomial(coefs, row, n, h, work, means):
    """
    Write the Chebyshev coefficients of a segment's sample mean as a function of its start.

    With ``E`` the antiderivative (rows ``row + 1 .. row + n + 1`` of ``coefs``) of a
    degree ``n`` fit ``p`` in the segment's variable ``u`` and ``h`` a sample's length in
    ``u``, ``q(u) = (E(u + h) - E(u)) / h = sum_{j >= 1} h^(j - 1) / j! E^(j)(u)``
    (Taylor's series, finite), written to rows ``row .. row + n`` of ``means``. The sum
    has no cancellation: with ``h n^2 <= 1`` (:data:`FAST_REACH`) the Chebyshev
    coefficients of ``E^(j)`` grow at most ``n^2`` a derivative (Markov), so the terms
    shrink at least like ``1 / j!``. ``work`` is (:data:`MAX_DEGREE` + 2, 6) work space.
    """
    for ch in range(6):
        work[0, ch] = 0.0
        for j in range(1, n + 2):
            work[j, ch] = coefs[row + j, ch]
        for j in range(n + 1):
            means[row + j, ch] = 0.0
    factor = 1.0
    for j in range(1, n + 2):
        top = n + 2 - j
        for ch in range(6):
            # Derivative in place: b_{k-1} = b_{k+1} + 2 k a_k, then b_0 halved.
            after, current = 0.0, 0.0
            for k in range(top, 0, -1):
                below = after + 2.0 * k * work[k, ch]
                work[k, ch] = current
                after, current = current, below
            work[0, ch] = 0.5 * current
            for k in range(top):
                means[row + k, ch] += factor * work[k, ch]
        factor *= h / (j + 1)


@njit(cache=True, nogil=True)
def _fast(start, period, k, low, high, n, means, row, u2, f, g, out_force, out_rate):
    """
    Write the means of samples ``k..`` lying wholly in ``[low, high]``; return the next.

    The caller has checked sample ``k``. Each mean is ``q`` of :func:`_mean_polynomial`
    at the sample's start, by Clenshaw's recurrence run over a block of samples at once
    (independent lanes the compiler vectorizes); ``u2``, ``f``, ``g`` (block,) are work
    space. Every sample's arithmetic is the same whatever the block it falls in.
    """
    count, end = out_force.shape[0], k + 1
    while end < count and start + (end + 1) * period <= high:
        end += 1
    for first in range(k, end, u2.shape[0]):
        size = min(u2.shape[0], end - first)
        for s in range(size):
            u2[s] = 2.0 * (2.0 * (start + (first + s) * period) - low - high) / (high - low)
        for ch in range(6):
            top = means[row + n, ch]
            for s in range(size):
                f[s], g[s] = top, 0.0
            for j in range(row + n - 1, row, -1):
                coefficient = means[j, ch]
                for s in range(size):
                    f[s], g[s] = u2[s] * f[s] - g[s] + coefficient, f[s]
            out, column, constant = (out_force, ch, means[row, ch]) if ch < 3 else \
                (out_rate, ch - 3, means[row, ch])
            for s in range(size):
                out[first + s, column] = 0.5 * u2[s] * f[s] - g[s] + constant
    return end


@njit(cache=True, nogil=True)
def _means(c, x, start, period, fast, rest, piece_start, piece_count, bounds, degree, offset,
           coefs, means, mean_period, out_force, out_rate):
    """
    Write the exact means of the fits over consecutive samples of ``period`` [s].

    With ``fast``, the samples wholly inside a segment take :func:`_fast` (``means``
    holds each segment's mean polynomial, built for ``mean_period`` [s]); the others,
    or all without ``fast``, integrate the fits piece by piece.
    """
    m = x.shape[0] - 1
    total = np.empty(6)
    point = np.empty(6)
    work = np.empty((MAX_DEGREE + 2, 6))
    u2, b1, b2 = np.empty(FAST_BLOCK), np.empty(FAST_BLOCK), np.empty(FAST_BLOCK)
    i = _piece(x, start, True)
    k = 0
    while k < out_force.shape[0]:
        a = start + k * period
        b = start + (k + 1) * period
        if fast and a >= x[0] and b <= x[m]:
            while i < m - 1 and a >= x[i + 1]:
                i += 1
            while i > 0 and a < x[i]:
                i -= 1
            if piece_count[i] > 0:
                g = piece_start[i]
                while bounds[g, 1] < x[i + 1] and a >= bounds[g, 1]:
                    g += 1
                n, span = degree[g], bounds[g, 1] - bounds[g, 0]
                if b <= bounds[g, 1] and 2.0 * period * n * n <= FAST_REACH * span:
                    if mean_period[g] != period:
                        _mean_polynomial(coefs, offset[g], n, 2.0 * period / span, work,
                                         means)
                        mean_period[g] = period
                    k = _fast(start, period, k, bounds[g, 0], bounds[g, 1], n, means,
                              offset[g], u2, b1, b2, out_force, out_rate)
                    continue
        before, after = max(min(b, x[0]) - a, 0.0), max(b - max(a, x[m]), 0.0)
        for ch in range(6):  # the body at rest before and after the pieces
            total[ch] = before * rest[0, ch] + after * rest[1, ch]
        low, high = max(a, x[0]), min(b, x[m])
        while low < high:
            while i < m - 1 and low >= x[i + 1]:
                i += 1
            while i > 0 and low < x[i]:
                i -= 1
            if piece_count[i] < 0:
                # A short piece: three-point Gauss-Legendre on its part of the sample.
                end = min(high, x[i + 1]) if i < m - 1 else high
                half = 0.5 * (end - low)
                for q in range(3):
                    sensed(c, i, low + half * (1.0 + _GAUSS_NODES[q]) - x[i], True, point)
                    for ch in range(6):
                        total[ch] += half * _GAUSS_WEIGHTS[q] * point[ch]
                low = end
                continue
            g = piece_start[i]
            while bounds[g, 1] < x[i + 1] and low >= bounds[g, 1]:
                g += 1
            end = min(high, bounds[g, 1])
            # The mean over [y, z] is sum_j e_j D_j, D_j = (T_j(z) - T_j(y)) / (z - y).
            span = bounds[g, 1] - bounds[g, 0]
            y = (2.0 * low - bounds[g, 0] - bounds[g, 1]) / span
            z = (2.0 * end - bounds[g, 0] - bounds[g, 1]) / span
            row = offset[g]
            v0 = v1 = v2 = v3 = v4 = v5 = 0.0
            d_previous, d_current = 0.0, 1.0
            t_previous, t_current = 1.0, y
            for j in range(1, degree[g] + 2):
                r = row + j
                v0 += coefs[r, 0] * d_current
                v1 += coefs[r, 1] * d_current
                v2 += coefs[r, 2] * d_current
                v3 += coefs[r, 3] * d_current
                v4 += coefs[r, 4] * d_current
                v5 += coefs[r, 5] * d_current
                d_previous, d_current = \
                    d_current, 2.0 * z * d_current + 2.0 * t_current - d_previous
                t_previous, t_current = t_current, 2.0 * y * t_current - t_previous
            weight = end - low
            total[0] += weight * v0
            total[1] += weight * v1
            total[2] += weight * v2
            total[3] += weight * v3
            total[4] += weight * v4
            total[5] += weight * v5
            low = end
        scale = 1.0 / (b - a)
        for ch in range(3):
            out_force[k, ch] = total[ch] * scale
            out_rate[k, ch] = total[3 + ch] * scale
        k += 1


@njit(cache=True, nogil=True)
def _sample_means(c, x, start, period, fast, shortest, tolerance, rest, piece_start,
                  piece_count, used, bounds, degree, offset, coefs, means, mean_period,
                  out_force, out_rate):
    """Fit the pieces the samples reach and write their means; False when storage is full."""
    m = x.shape[0] - 1
    low = min(max(start, x[0]), x[m])
    high = min(max(start + out_force.shape[0] * period, x[0]), x[m])
    first, last = _piece(x, low, True), _piece(x, high, False)
    if not _build(c, x, first, last, shortest, tolerance, piece_start, piece_count, bounds,
                  degree, offset, coefs, used):
        return False
    _means(c, x, start, period, fast, rest, piece_start, piece_count, bounds, degree, offset,
           coefs, means, mean_period, out_force, out_rate)
    return True


class PiecewiseMeans:
    """
    Sample means of f^b and w_ib^b of a moving trajectory, from per-piece verified fits.

    Parameters
    ----------
    c : numpy.ndarray
        ``PPoly`` coefficients (k, m, 6) of lat, lon [rad], h [m], roll, pitch, yaw [rad].
    x : numpy.ndarray
        Breakpoints (m + 1,) [s], strictly increasing.
    fast : bool
        Take each segment's mean polynomial for the samples wholly inside it (the
        default); False integrates every sample (the slower path, kept for comparison).
    """

    def __init__(self, c, x, fast=True):
        self._c = np.ascontiguousarray(c, dtype=float)
        self._x = np.ascontiguousarray(x, dtype=float)
        m = self._x.shape[0] - 1
        if self._c.ndim != 3 or self._c.shape[1:] != (m, 6) or m < 1:
            raise ValueError('c must have shape (k, m, 6) for m + 1 breakpoints x')
        self._fast = bool(fast)
        self._tolerance = np.array([FORCE_TOLERANCE, RATE_TOLERANCE, RELATIVE_TOLERANCE])
        self._rest = np.empty((2, 6))
        sensed(self._c, 0, 0.0, False, self._rest[0])
        sensed(self._c, m - 1, self._x[m] - self._x[m - 1], False, self._rest[1])
        self._piece_start = np.zeros(m, dtype=np.int64)
        self._piece_count = np.zeros(m, dtype=np.int64)
        self._used = np.zeros(2, dtype=np.int64)
        # The segment storage (doubled by _grow when full): 64 segments, 576 coefficient rows.
        self._bounds, self._mean_period = np.empty((64, 2)), np.full(64, np.nan)
        self._degree, self._offset = np.zeros(64, dtype=np.int64), np.zeros(64, dtype=np.int64)
        self._coefs, self._means = np.empty((64 * 9, 6)), np.empty((64 * 9, 6))

    def _grow(self):
        """Double the segment storage, keeping its contents (no mean polynomial built after)."""
        for name in ('_bounds', '_degree', '_offset', '_coefs', '_means', '_mean_period'):
            old = getattr(self, name)
            grown = np.empty((2 * len(old),) + old.shape[1:], old.dtype)
            grown[:len(old)] = old
            setattr(self, name, grown)
        self._mean_period[len(self._mean_period) // 2:] = np.nan

    @property
    def segments(self):
        """Return the (start, end) [s] and degree of every segment fitted so far."""
        used = self._used[0]
        return self._bounds[:used].copy(), self._degree[:used].copy()

    def sample_means(self, start, period, n):
        """
        Return (mean f^b (n, 3) [m/s^2], mean w_ib^b (n, 3) [rad/s]) over ``n`` samples.

        Sample ``k`` spans ``[start + k period, start + (k + 1) period]`` [s].
        """
        start, period = float(start), float(period)
        if not period > 0:
            raise ValueError('period must be positive')
        force, rate = np.empty((n, 3)), np.empty((n, 3))
        if n == 0:
            return force, rate
        while not _sample_means(self._c, self._x, start, period, self._fast,
                                DIRECT_SAMPLES * period, self._tolerance, self._rest,
                                self._piece_start, self._piece_count, self._used,
                                self._bounds, self._degree, self._offset, self._coefs,
                                self._means, self._mean_period, force, rate):
            self._grow()
        return force, rate
