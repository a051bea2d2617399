#!/usr/bin/env bash
# The GPU checks of issues 16 and 18 in one run on a lent CUDA machine (the workplace's device
# tool: docs/physics-core.md, "Running it on a GPU"). That machine's image has Python 3.12 with
# numpy, scipy, tqdm and pytest but not softvr's other needs: scripts/device_wheels.sh fetches
# them here into .whl/1, .whl/2, ... (warp-lang in parts; VTK and SimpleITK are not needed: the
# physics and its benches run headless without them), with every kernel module compiled for sm_90
# there (kernels.tgz: scripts/device_kernels.py), one folder for each device call to carry on one
# warm machine. Each call runs this script: it keeps the parts that came (in /tmp/parts) and, once
# .whl's MANIFEST is all there, installs them, loads every module on the CPU and the GPU in
# parallel, and runs the checks, logs and JSONs to $OUT. Each stage has its own timeout; the
# whole is sized for one 10-minute call.
# `bash scripts/device_check.sh profile` (a further call on the same warm machine, where device
# time is left) runs scripts/device_profile.py instead: device time per kernel of the candy, the
# shoulder and 64 cubes, the candy's step with PARALLEL_PASS_FACTOR 1, 2, 4, and each scene's
# step with the sweeps' stop on the device and on the host.
set -u
OUT=${OUT:-device-out}
mkdir -p "$OUT" /tmp/parts /tmp/site
export PYTHONUNBUFFERED=1 PYTHONPATH=/tmp/site:$PWD/src SOFTVR_DATA=/tmp/parts
cp .whl/*/* /tmp/parts/ 2>/dev/null
if ! python3 -c "import warp" 2>/dev/null; then
    if [ ! -f /tmp/parts/MANIFEST ] || ! (cd /tmp/parts && xargs ls < MANIFEST > /dev/null 2>&1); then
        echo "have: $(ls /tmp/parts | tr '\n' ' ')- waiting for the rest of .whl (MANIFEST comes last)"
        exit 0
    fi
    for first in /tmp/parts/*.whl.part-00; do
        cat "${first%-00}"-* > "${first%.part-00}"
    done
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site /tmp/parts/*.whl \
        || exit 1
fi
nvidia-smi > "$OUT/nvidia-smi.txt" 2>&1
# The kernels compiled for sm_90 where the wheels were fetched (scripts/device_kernels.py): Warp
# loads a module's cubin from this cache where the driver takes cubins, else compiles as before.
if [ -f /tmp/parts/kernels.tgz ] && [ ! -d /tmp/kernels-cache ]; then
    tar xzf /tmp/parts/kernels.tgz -C /tmp
fi
[ -d /tmp/kernels-cache ] && export WARP_CACHE_PATH=/tmp/kernels-cache
# Every module loaded on the CPU and the GPU in parallel, a process a core (compiling what the
# cache lacks: the CPU's objects always), so that no test or bench compiles one after another.
# ($OUT/kernels.txt keeps Warp's lines: "load on device 'cuda:0' ... (cached)" where a cubin of
# kernels.tgz was taken, "(compiled)" where not.)
if [ ! -f /tmp/kernels-loaded ]; then
    timeout 150 python3 scripts/device_kernels.py --load cpu cuda > "$OUT/kernels.txt" 2>&1
    grep -v "^Module " "$OUT/kernels.txt" | tail -12
    touch /tmp/kernels-loaded
fi
if [ "${1:-}" = profile ]; then
    timeout 540 python3 scripts/device_profile.py "$OUT" 2>&1 | tee "$OUT/profile.txt" | tail -80
    exit 0
fi
# The node step on CUDA against the CPU's, the host mirror, the thread-per-contact passes against
# SciPy's LCP on CUDA (their atomics for real). (tests/test_cuda_build.py, every module through
# NVRTC, runs in CI without a GPU: here it would compile them all again, ~3.5 minutes.)
timeout 240 python3 -m pytest -q -p no:cacheprovider tests/test_device.py tests/sim/test_node_device.py \
    tests/contact/test_node_parallel_contacts.py 2>&1 | tee "$OUT/tests.txt" | tail -30
# The GPU targets: 64 cubes >= 1000 steps/s each, candy <= 4 ms a step, shoulder <= 1 ms.
timeout 200 python3 -m softvr bench contact --device cuda --engines softvr --cubes 64 --no-progress \
    --json "$OUT/contact_cuda.json" 2>&1 | tee "$OUT/contact_cuda.txt" | tail -20
timeout 120 python3 -m softvr bench shoulder --device cuda --no-progress --json "$OUT/shoulder_cuda.json" 2>&1 \
    | tee "$OUT/shoulder_cuda.txt" | tail -12
# Issue 18's GPU frame (<= 5 ms), where VTK came (device_wheels.sh --vtk) and has an OpenGL context.
if python3 -c "import vtk" 2>/dev/null; then
    timeout 150 python3 -m softvr bench palpation --device cuda --no-progress --json "$OUT/palpation_cuda.json" \
        2>&1 | tee "$OUT/palpation_cuda.txt" | tail -20
fi
