"""The body-state stream against exact arithmetic and SciPy.

Truths: quantized integers add exactly, so a decoder that applied every delta holds the
encoder's integers bit for bit and every vertex is within quantum / 2 of the simulation
(rounding to the nearest multiple); a rigidly moved mesh is sent as a pose whose rotation is
SciPy's (Kabsch on noise-free points is exact to round-off); corrupt or oversized mesh data
raises ``ValueError`` instead of allocating.
"""

import zlib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from softvr.cave.app import WavingSheet
from softvr.cave.protocol import encode
from softvr.cave.stream import MeshDecoder, MeshEncoder, fit_rigid, pose_matrix


def test_deltas_reproduce_the_quantized_positions_exactly():
    rng = np.random.default_rng(0)
    rest = rng.uniform(-0.5, 0.5, (500, 3))
    enc, dec = MeshEncoder(rest, 1e-5, rigid=False), MeshDecoder(rest, 1e-5)
    x = rest.copy()
    widths = set()
    for step in range(60):
        # Small, medium and large moves: every packing width is used.
        x = x + rng.normal(0, [1e-4, 1e-2, 0.2][step % 3], x.shape)
        update = enc.encode(x)
        if update[0] == "delta":
            widths.add(update[1])
        dec.apply(update)
        np.testing.assert_array_equal(dec.ints, np.rint(x / 1e-5).astype(np.int64))
        assert np.abs(dec.vertices() - x).max() <= 0.5e-5 * (1 + 1e-9)
    assert widths == {1, 2, 4}
    assert enc.encode(x) is None  # nothing moved: nothing sent


def test_a_rigid_motion_is_sent_as_scipys_pose():
    rng = np.random.default_rng(1)
    rest = rng.uniform(-0.1, 0.1, (200, 3))
    rotation = Rotation.from_rotvec([0.3, -1.1, 0.7])
    moved = rotation.apply(rest) + [0.4, 0.1, -2.0]
    pose, error = fit_rigid(rest, moved)
    assert error < 1e-12
    expected = rotation.as_quat()[[3, 0, 1, 2]]  # SciPy is scalar-last
    assert min(np.abs(pose[3:] - expected).max(), np.abs(pose[3:] + expected).max()) < 1e-12
    np.testing.assert_allclose(pose_matrix(pose)[0], rotation.as_matrix(), atol=1e-12)
    enc, dec = MeshEncoder(rest), MeshDecoder(rest)
    update = enc.encode(moved)
    assert update[0] == "pose"
    dec.apply(update)
    np.testing.assert_allclose(dec.vertices(), moved, atol=1e-12)
    # Then it deforms: a key (absolute integers) follows a pose, never a delta against it.
    bent = moved.copy()
    bent[0] += 0.01
    assert enc.encode(bent)[0] == "key"


def test_a_10k_vertex_deforming_body_streams_under_100_kb_per_frame():
    """The issue's target for streamed deformable state; the sheet moves up to 5 cm/s."""
    sheet = WavingSheet(10_000)
    encoders = {h: MeshEncoder(i["rest"]) for h, i in enumerate(sheet.items) if i["kind"] == "mesh"}
    sizes = []
    for n in range(30):
        vertices = sheet.advance()
        meshes = [[h, *u] for h, e in encoders.items() if (u := e.encode(vertices[h])) is not None]
        sizes.append(len(encode("frame", 1, {"n": n, "t": 0.0, "user": np.eye(4).ravel().tolist(),
                                              "head": [0, 0, 1.7, 1, 0, 0, 0], "events": [], "meshes": meshes})))
    assert max(sizes[1:]) < 100_000, sizes


@pytest.mark.parametrize("data", [b"garbage", zlib.compress(b"\0" * 10), zlib.compress(b"\0" * (1 << 24))])
def test_corrupt_or_oversized_mesh_data_is_refused(data):
    dec = MeshDecoder(np.zeros((4, 3)))
    with pytest.raises(ValueError):
        dec.apply(["key", data])
    with pytest.raises(ValueError, match="no key"):
        dec.apply(["delta", 1, zlib.compress(b"\0" * 12)])
