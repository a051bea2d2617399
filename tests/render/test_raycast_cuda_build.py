"""The ray caster's kernels compile for CUDA (sm_90, through NVRTC) on a machine without a GPU:
the one kernel source is CUDA-ready (CPU/CUDA image agreement runs wherever a GPU is present)."""

import pytest
import warp as wp

from softvr.render import _raycast_kernels


def test_raycast_kernels_compile_to_ptx(tmp_path):
    try:
        wp.compile_aot_module(_raycast_kernels, arch=90, module_dir=str(tmp_path), use_ptx=True)
    except Exception as exc:  # a wheel without NVRTC cannot build CUDA code at all
        if "nvrtc" in str(exc).lower() and "not" in str(exc).lower():
            pytest.skip(f"Warp has no NVRTC here: {exc}")
        raise
    ptx = list(tmp_path.glob("*.sm90.ptx"))
    assert len(ptx) == 1
    text = ptx[0].read_text()
    for kernel in ("raycast", "brick_minmax", "brick_occupancy", "brick_distance_pass"):
        assert kernel in text
