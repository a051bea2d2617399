"""The directions a haptic tool's pushing contacts block (thesis 5.4: the handle model's
stiffness K = -k P, P the projector onto the span of the pushing normals), in closed form
(:func:`softvr.haptics.tool.blocked_span`).

Truth: NumPy's SVD (LAPACK dgesdd) of the k x 3 normals N: the right singular vectors whose
singular values exceed 1e-3 of the largest, and P = V^T V. Away from that cut (sets whose
singular value ratios lie within 10 % of 1e-3 are left out: there either rank is right), the
closed form's eigenvalues of N^T N are exact to a few u (u = 1.1e-16) of themselves and its
eigenvectors to ~u l1 / gap; the gap to a rank-2 set's free direction is at least
s1^2 - s2^2 >= (0.9e-3)^2 s0^2 - ... ~ 1e-7 s0^2 here, so P is within ~1e-9 of the SVD's:
tolerance 1e-8 (measured: 4e-11 at worst over these sets). Rows orthonormal to 10 u.
"""

import numpy as np
import pytest

from softvr.haptics.tool import RANK_TOLERANCE, blocked_span


def _truth(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    _, s, vt = np.linalg.svd(n, full_matrices=False)
    rows = vt[s > RANK_TOLERANCE * s[0]]
    return rows, rows.T @ rows


def _sets(rng, k: int, count: int):
    """``count`` sets of k normals [k, 3]: random, nearly parallel, nearly in a plane, or along
    the axes (exact double and triple eigenvalues), of lengths 0.5-2."""
    for t in range(count):
        n = rng.standard_normal((k, 3)) * rng.uniform(0.5, 2.0)
        kind = t % 4
        if kind == 1 and k > 1:
            n = n[0] + rng.standard_normal((k, 3)) * 10 ** rng.uniform(-9, -0.5)
        elif kind == 2 and k > 2:
            w = np.cross(n[0], n[1])
            w /= np.linalg.norm(w)
            n = n - np.outer(n @ w, w) * (1 - 10 ** rng.uniform(-9, -0.5))
        elif kind == 3:
            n = np.eye(3)[rng.integers(0, 3, k)] * rng.choice([-1.0, 1.0], (k, 1))
        s = np.linalg.svd(n, compute_uv=False)
        if not np.any(np.abs(s / s[0] / RANK_TOLERANCE - 1.0) < 0.1):
            yield n


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
def test_blocked_span_is_the_svds_span_and_projector(k):
    rng = np.random.default_rng(k)
    ranks = set()
    for n in _sets(rng, k, 1000):
        rows, projector = (np.array(x) for x in blocked_span(n.tolist()))
        truth_rows, truth_projector = _truth(n)
        assert rows.shape == truth_rows.shape, n
        np.testing.assert_allclose(projector, truth_projector, rtol=0, atol=1e-8)
        np.testing.assert_allclose(rows @ rows.T, np.eye(len(rows)), rtol=0, atol=1e-15)
        np.testing.assert_allclose(rows.T @ rows, truth_projector, rtol=0, atol=1e-8)
        ranks.add(len(rows))
    assert ranks == set(range(1, min(k, 3) + 1))  # every rank the sets can have was met
