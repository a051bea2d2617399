"""Shared shapes against geometry: the box's triangles enclose its volume (8 hx hy hz by the
divergence theorem, so they are closed and outward) and the icosphere's vertices lie on the
unit sphere with an enclosed volume approaching 4/3 pi from below."""

import numpy as np
import pytest

from softvr.model import BOX_TRIANGLES, box_corners, icosphere


def _enclosed(v, t):
    a, b, c = (v[t[:, i]] for i in range(3))
    return np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0


def test_box_triangles_close_the_box_outwards():
    assert _enclosed(box_corners((0.5, 1.0, 2.0)), BOX_TRIANGLES) == pytest.approx(8 * 0.5 * 1.0 * 2.0)


def test_icosphere_is_a_closed_unit_sphere():
    v, t = icosphere(3)
    assert np.allclose(np.linalg.norm(v, axis=1), 1.0)
    assert 0.98 * 4 / 3 * np.pi < _enclosed(v, t) < 4 / 3 * np.pi
