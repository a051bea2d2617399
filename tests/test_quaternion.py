"""softvr's quaternions, (w, x, y, z), held to SciPy's ``Rotation`` / ``Slerp`` (x, y, z, w).

One helper set (:mod:`softvr.dynamics.rigid`) and the places that use SciPy directly (head
tracking, the cluster's pose stream) must agree with SciPy on random rotations: the same
rotation matrices, the same composition order, the same slerp. Tolerances are round-off of a
few float64 operations (1e-14 on unit quantities, 1e-12 after a slerp or an SVD fit).
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from softvr.cave import HeadPose, ScriptedTracker, quaternion_about
from softvr.cave.stream import fit_rigid, pose_matrix
from softvr.dynamics.rigid import quat_conjugate, quat_from_rotvec, quat_multiply, quat_to_matrix, quat_to_rotvec

RNG = np.random.default_rng(20)
A = Rotation.random(50, random_state=1)
B = Rotation.random(50, random_state=2)


def wxyz(r: Rotation) -> np.ndarray:
    return np.roll(r.as_quat(), 1, axis=-1)


def same_rotation(q, r: Rotation, atol=1e-14):
    """``q`` (w, x, y, z) is ``r`` up to the sign of the quaternion (q and -q: one rotation)."""
    ref = wxyz(r)
    sign = np.sign(np.sum(q * ref, axis=-1, keepdims=True))
    np.testing.assert_allclose(q, sign * ref, atol=atol)


def test_helpers_match_scipy_one_by_one_and_batched():
    """Product (a then b is b * a in SciPy's right-to-left order), conjugate (the inverse),
    matrix, and both rotation-vector maps, for 50 random pairs and for one quaternion alone."""
    a, b = wxyz(A), wxyz(B)
    same_rotation(quat_multiply(a, b), A * B)
    same_rotation(quat_conjugate(a), A.inv())
    np.testing.assert_allclose(quat_to_matrix(a), A.as_matrix(), atol=1e-14)
    np.testing.assert_allclose(quat_to_rotvec(a), A.as_rotvec(), atol=1e-13)
    phi = RNG.normal(size=(50, 3))
    same_rotation(quat_from_rotvec(phi), Rotation.from_rotvec(phi))
    for i in (0, 17):  # the single-quaternion path (plain floats) of quat_to_matrix, and the others
        np.testing.assert_allclose(quat_to_matrix(a[i]), A[i].as_matrix(), atol=1e-14)
        same_rotation(quat_multiply(a[i], b[i]), A[i] * B[i])
        np.testing.assert_allclose(quat_to_rotvec(quat_from_rotvec(phi[i])), Rotation.from_rotvec(phi[i]).as_rotvec(),
                                   atol=1e-14)


def test_rotation_vector_of_q_and_minus_q_is_the_short_one():
    """q and -q give the same rotation vector, of angle in [0, pi] (SciPy's convention)."""
    a = wxyz(A)
    np.testing.assert_allclose(quat_to_rotvec(-a), quat_to_rotvec(a), atol=1e-14)
    assert np.all(np.linalg.norm(quat_to_rotvec(a), axis=-1) <= np.pi + 1e-14)


def test_tracking_quaternions_match_scipy():
    """``quaternion_about``, ``HeadPose.rotation`` and the scripted tracker's slerp against
    ``Rotation.from_rotvec``, ``as_matrix`` and ``Slerp`` over three random keyframes."""
    axis, angle = RNG.normal(size=3), 2.3
    same_rotation(np.array(quaternion_about(axis, angle)), Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)))
    pose = HeadPose((0.0, 0.0, 1.7), wxyz(A[3]))
    np.testing.assert_allclose(pose.rotation, A[3].as_matrix(), atol=1e-14)
    times = [0.0, 1.0, 2.5]
    keys = A[:3]
    path = ScriptedTracker(times, np.zeros((3, 3)), wxyz(keys), clock=lambda: 0.0)
    ref = Slerp(times, keys)
    for t in (0.0, 0.3, 1.0, 1.7, 2.5):
        same_rotation(np.array(path.pose_at(t).orientation), ref(t), atol=1e-12)


def test_stream_poses_match_scipy():
    """The cluster stream's pose matrix is SciPy's, and a rigidly moved mesh fits back to the
    rotation that moved it (Kabsch, then the quaternion of its matrix)."""
    q = wxyz(A[5])
    rotation, translation = pose_matrix(np.r_[0.1, 0.2, 0.3, 2.0 * q])  # not unit: normalised
    np.testing.assert_allclose(rotation, A[5].as_matrix(), atol=1e-14)
    np.testing.assert_array_equal(translation, [0.1, 0.2, 0.3])
    rest = RNG.normal(size=(40, 3))
    pose, error = fit_rigid(rest, A[6].apply(rest) + (1.0, -2.0, 0.5))
    same_rotation(pose[3:], A[6], atol=1e-12)
    np.testing.assert_allclose(pose[:3], [1.0, -2.0, 0.5], atol=1e-12)
    assert error == pytest.approx(0.0, abs=1e-12)


def test_single_quaternion_paths_give_scipys_bits():
    """The plain-float paths a kinematic body takes every step: one product, and the rotation
    vector of a quaternion with no vector part (no turn over the step; zeros of either sign)
    are bit for bit SciPy's (the batched product's, and ``Rotation.as_rotvec``'s small-angle
    map ``2 (x, y, z)``, which keeps the zeros' signs), so a kinematic body steps the same."""
    a, b = wxyz(A), wxyz(B)
    batched = quat_multiply(a, b)
    for i in range(len(a)):
        assert quat_multiply(a[i], b[i]).tobytes() == batched[i].tobytes()
    for q in ([1.0, 0.0, 0.0, 0.0], [1.0, -0.0, 0.0, -0.0], [1.0 - 2 ** -53, -0.0, -0.0, -0.0],
              quat_multiply(a[3], quat_conjugate(a[3]))):
        q = np.asarray(q)
        assert not q[1:].any()
        assert quat_to_rotvec(q).tobytes() == Rotation.from_quat(q[[1, 2, 3, 0]]).as_rotvec().tobytes()
