"""Compile every softvr kernel module for a CUDA GPU here, ahead of time, through the NVRTC in
Warp's wheel (no GPU needed), into a Warp kernel cache that a lent GPU machine then uses:
``python3 scripts/device_kernels.py CACHE [ARCH]`` (default sm_90: H100, H200).

A fresh device machine would otherwise compile each module on its first use, one after another
(measured here: the collision module alone 70 s, six of the largest 107 s), out of the session's
few minutes of device time. Warp looks a module's binary up in its kernel cache by the module's
content hash, the target architecture and the output kind (``WARP_CACHE_PATH``; file
``wp_<module>_<hash>/wp_<module>_<hash>.sm<ARCH>.cubin``), the names ``wp.compile_aot_module``
writes: where the machine's driver takes cubins for that architecture (Warp's own choice there),
it loads these instead of compiling; elsewhere (PTX, another architecture or hash) it compiles
as before. ``scripts/device_wheels.sh`` runs this and packs ``CACHE`` into a folder the device
calls carry; ``scripts/device_check.sh`` points ``WARP_CACHE_PATH`` at it there.

``python3 scripts/device_kernels.py --load DEVICE...`` (on the device machine, first) loads every
module on each device in parallel processes, one a core, into the kernel cache: what the CPU
needs (its objects are built for the machine's own CPU, so they cannot come from here: ~90 s of
compiling one after another here, the ray caster's module alone 13 s) and whatever CUDA binary
the cache lacked, so that the tests and benches after it find every module compiled.
"""

from __future__ import annotations

import importlib
import multiprocessing
import os
import pkgutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import warp as wp
from warp._src import context

import softvr

wp.config.quiet = True


def kernel_modules() -> list[str]:
    """Names of softvr's modules that declare Warp kernels (every package imported)."""
    for info in pkgutil.walk_packages(softvr.__path__, "softvr."):
        if info.name.endswith("__main__"):
            continue
        try:
            importlib.import_module(info.name)
        except ImportError:  # an optional part (the Blender add-on needs bpy)
            continue
    return sorted(name for name in context.user_modules if name.startswith("softvr."))


def _pool() -> ProcessPoolExecutor:
    """A process a core, each started afresh (spawned, not forked: a CUDA context does not
    survive a fork, so none may be inherited)."""
    return ProcessPoolExecutor(max_workers=os.cpu_count(), mp_context=multiprocessing.get_context("spawn"))


def compile_one(name: str, arch: int) -> tuple[str, float, str]:
    """Compile module ``name`` for ``arch`` into the kernel cache (``WARP_CACHE_PATH``): its name,
    the seconds it took and, where it does not compile for CUDA, why (a module of functions
    only; the factored solve's module, which is CPU only and is never loaded on a GPU)."""
    start = time.perf_counter()
    try:
        wp.compile_aot_module(importlib.import_module(name), arch=arch, use_ptx=False)
    except Exception as exc:  # noqa: BLE001 - Warp raises a bare Exception for a failed CUDA build
        return name, time.perf_counter() - start, str(exc).splitlines()[0][:100]
    return name, time.perf_counter() - start, ""


def load_one(name: str, device: str) -> tuple[str, str, float, str]:
    """Load module ``name`` on ``device`` (compiling it into the kernel cache where it is not
    there): its name, the device, the seconds it took and, where it failed, why."""
    start = time.perf_counter()
    try:
        wp.load_module(importlib.import_module(name), device=device)
    except Exception as exc:  # noqa: BLE001 - the factored solve's module is CPU only
        return name, device, time.perf_counter() - start, str(exc).splitlines()[0][:100]
    return name, device, time.perf_counter() - start, ""


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__)
        return 2
    if argv[0] == "--load":
        names = kernel_modules()
        jobs = [(name, device) for device in argv[1:] for name in names]
        start = time.perf_counter()
        with _pool() as pool:
            for name, device, seconds, failed in pool.map(load_one, *zip(*jobs)):
                if seconds > 1.0 or failed:
                    print(f"{seconds:6.1f} s  {name} on {device}" + (f"  (not loaded: {failed})" if failed else ""),
                          flush=True)
        print(f"device_kernels: {len(names)} modules loaded on {', '.join(argv[1:])} in "
              f"{time.perf_counter() - start:.0f} s")
        return 0
    os.environ["WARP_CACHE_PATH"] = os.path.abspath(argv[0])
    arch = int(argv[1]) if len(argv) > 1 else 90
    names = kernel_modules()
    with _pool() as pool:
        done = 0
        for name, seconds, skipped in pool.map(compile_one, names, [arch] * len(names)):
            print(f"{seconds:6.1f} s  {name}" + (f"  (not compiled: {skipped})" if skipped else ""), flush=True)
            done += not skipped
    print(f"device_kernels: {done} of {len(names)} modules for sm_{arch} in {argv[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
