"""Every module of compiled kernels compiles for CUDA (sm_90, through NVRTC) on a machine
without a GPU: the one kernel source is CUDA-ready, and CUDA-only compile errors (CPU C++
snippets not fenced off from device code, host-only calls) show in CI. The CPU/CUDA agreement
tests themselves run wherever a GPU is present."""

import importlib

import pytest
import warp as wp

MODULES = {
    "softvr.volume._raster_kernels": ("raster_slabs", "raster_cells", "point_masks", "cell_masks", "tet_setup"),
    "softvr.render._raycast_kernels": ("raycast", "brick_minmax", "brick_distance_pass", "brick_changes",
                                       "stale_pixels", "mark_pixels"),
    "softvr.dynamics._rigid_kernels": ("unconstrained", "integrate"),
    "softvr.collision._primitive_kernels": ("points_plane", "boxes_plane", "spheres_plane", "sphere_pairs",
                                            "box_pairs"),
    "softvr.contact._rigid_pgs_kernels": ("solve_rigid_contacts",),
    "softvr.dynamics._fem_kernels": ("_corotated_kernel",),
    "softvr.dynamics._node_kernels": ("element_terms", "element_terms_isotropic", "assemble", "assemble_isotropic",
                                      "right_hand_side", "integrate", "start_guess", "share_sums", "share_sums_parallel",
                                      "share_total",
                                      "rigid_start_guess", "drive"),
    "softvr.collision._node_kernels": ("point_motion", "body_motion", "body_bounds", "near_bodies", "vertex_triangle",
                                       "face_normals", "edge_geometry", "body_creases", "edge_edge",
                                       "point_static_mesh", "gather_contacts", "carry_impulses",
                                       "gather_pairs", "clear_carried", "carry_parallel"),
    "softvr.contact._node_jacobi_kernels": ("jacobi", "contact_metric", "contacts", "chebyshev", "residual",
                                            "rigid_contact_exact", "largest_change", "screen", "contact_step"),
    "softvr.contact._node_parallel_kernels": ("contact_step_unshared", "residual_parallel"),
    "softvr.contact._node_block_kernels": ("contact_step_block", "gauss_seidel_before_contacts",
                                           "gauss_seidel_after_contacts"),
    "softvr.contact._node_loop_kernels": ("begin", "check_change", "check_stop"),
    "softvr.contact._node_coarse_kernels": ("prepare_bodies", "contact_sides", "coarse_residual", "body_mass_parallel",
                                            "body_centre_parallel", "body_blocks_parallel", "body_inverse_parallel",
                                            "residual_sums_parallel", "coarse_solve_parallel"),
    "softvr.contact._node_gs_kernels": ("gauss_seidel", "gauss_seidel_walk", "contact_nodes", "listed_contact_nodes",
                                        "list_contact_nodes", "projected",
                                        "mark_contact_nodes", "gather_off_blocks", "woken_parallel",
                                        "island_force_clear", "island_force_add", "island_respond"),
    "softvr.contact._node_gs_coarse_kernels": ("prepare_aggregates", "coarse_velocities", "apply_coarse"),
    "softvr.contact._node_adhesion_kernels": ("prepare", "evolve", "evolve_parallel", "carry_parallel"),
    "softvr.dynamics._node_coupling_kernels": ("coupling_stretch", "coupling_blocks", "coupling_forces",
                                               "pair_inverse"),
    "softvr.dynamics._node_rigid_kernels": ("rigid_system", "rigid_velocity"),
    "softvr.dynamics._node_cloth_kernels": ("spring_terms", "spring_blocks", "spring_forces"),
    "softvr.collision._node_rigid_kernels": ("rigid_points", "rigid_sides", "primitive_contacts"),
    "softvr.device": ("_copy_int32",),
}


@pytest.mark.parametrize("name", MODULES)
def test_kernels_compile_to_ptx(name, tmp_path):
    try:
        wp.compile_aot_module(importlib.import_module(name), arch=90, module_dir=str(tmp_path), use_ptx=True)
    except Exception as exc:  # a wheel without NVRTC cannot build CUDA code at all
        if "nvrtc" in str(exc).lower() and "not" in str(exc).lower():
            pytest.skip(f"Warp has no NVRTC here: {exc}")
        raise
    ptx = list(tmp_path.glob("*.sm90.ptx"))
    assert len(ptx) == 1
    text = ptx[0].read_text()
    for kernel in MODULES[name]:
        assert kernel in text


def test_the_device_checks_kernel_cache_takes_every_module_that_declares_a_kernel():
    # scripts/device_kernels.py compiles what it finds through Warp's module registry after
    # importing every package; the truth here is the source text: every file under src/softvr
    # with a kernel decorator (the Blender add-on aside: it needs bpy, and declares none).
    import pathlib
    import re
    import sys

    root = pathlib.Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(root / "scripts"))
    try:
        import device_kernels
    finally:
        sys.path.pop(0)
    declared = {".".join(path.relative_to(root / "src").with_suffix("").parts)
                for path in (root / "src" / "softvr").rglob("*.py")
                if re.search(r"^@wp\.kernel", path.read_text(), re.MULTILINE)}
    assert declared and declared <= set(device_kernels.kernel_modules())
