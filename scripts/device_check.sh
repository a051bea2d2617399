#!/usr/bin/env bash
# The GPU checks of issues 16 and 18 in one run on a lent CUDA machine (the workplace's device
# tool: docs/physics-core.md, "Running it on a GPU"). That machine's image has Python 3.12 with
# numpy, scipy, tqdm and pytest but not softvr's other needs; this expects, in .whl/ (an ignored
# folder the calls carry, 64 MiB a call), the wheels for Python 3.12 of
#   warp-lang (149 MB: carried as parts warp.part-aa, -ab, ... over several calls of one warm
#   machine, each part copied to /tmp/parts by its call), trimesh, fast-simplification,
#   pydantic, pydantic-core, annotated-types and typing-inspection
# (VTK is not needed: the physics and its benches run headless without it). Writes the logs and
# JSONs to $OUT. Each stage has its own timeout; the whole is sized for one 10-minute call.
set -u
OUT=${OUT:-device-out}
mkdir -p "$OUT" /tmp/parts /tmp/site
export PYTHONUNBUFFERED=1 PYTHONPATH=/tmp/site:$PWD/src
cp .whl/* /tmp/parts/ 2>/dev/null
if ! python3 -c "import warp" 2>/dev/null; then
    cat /tmp/parts/warp.part-* > /tmp/warp_lang-1.19.0-py3-none-manylinux_2_28_x86_64.whl || exit 1
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site \
        /tmp/warp_lang-1.19.0-py3-none-manylinux_2_28_x86_64.whl /tmp/parts/*.whl || exit 1
fi
nvidia-smi > "$OUT/nvidia-smi.txt" 2>&1
# The node step on CUDA against the CPU's, the host mirror, every kernel module's PTX.
timeout 240 python3 -m pytest -q -p no:cacheprovider tests/test_device.py tests/sim/test_node_device.py \
    tests/test_cuda_build.py 2>&1 | tee "$OUT/tests.txt" | tail -30
# The GPU targets: 64 cubes >= 1000 steps/s each, candy <= 4 ms a step, shoulder <= 1 ms.
timeout 200 python3 -m softvr bench contact --device cuda --engines softvr --cubes 64 --no-progress \
    --json "$OUT/contact_cuda.json" 2>&1 | tee "$OUT/contact_cuda.txt" | tail -20
timeout 120 python3 -m softvr bench shoulder --device cuda --no-progress --json "$OUT/shoulder_cuda.json" 2>&1 \
    | tee "$OUT/shoulder_cuda.txt" | tail -12
