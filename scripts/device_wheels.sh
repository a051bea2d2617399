#!/usr/bin/env bash
# Fetch, here (where pip reaches PyPI), the wheels scripts/device_check.sh installs on a lent GPU
# machine (Python 3.12, no network): the versions this checkout's .venv holds, into .whl/ (ignored
# by git), warp-lang's 149 MB split into parts so that each device call carries one folder under
# the 64 MiB a call may carry: carry .whl/1, then .whl/2, ... on one warm machine, each call
# running `bash scripts/device_check.sh` (it keeps what came and runs the checks once all is there).
# With --vtk also VTK and the head CT (softvr bench palpation on the GPU: four more folders; VTK
# also needs an OpenGL context there: EGL, see the device tool's README).
set -euo pipefail
cd "$(dirname "$0")/.."
grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo '/.whl/' >> .git/info/exclude
py=.venv/bin/python
packages=(warp-lang trimesh fast-simplification pydantic pydantic-core annotated-types typing-inspection typing-extensions)
[ "${1:-}" = "--vtk" ] && packages+=(vtk)
pins=()
for p in "${packages[@]}"; do pins+=("$p==$($py -c "import importlib.metadata as m; print(m.version('$p'))")"); done
rm -rf .whl && mkdir -p .whl/dl
$py -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_24_x86_64 \
    --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl/dl "${pins[@]}"
# Big wheels as 50 MB parts, one folder each.
k=0
for big in .whl/dl/warp_lang-*.whl .whl/dl/vtk-*.whl; do
    [ -f "$big" ] || continue
    name=$(basename "$big")
    split -b 50M -d "$big" ".whl/dl/$name.part-"
    for part in ".whl/dl/$name.part-"*; do
        k=$((k + 1)); mkdir -p ".whl/$k"; mv "$part" ".whl/$k/"
    done
    rm "$big"
done
# Every kernel module compiled for the GPU (sm_90) here, through the wheel's NVRTC: the device
# machine loads them from this cache instead of compiling each on its first use (~3.5 minutes of
# NVRTC here, the collision module alone ~1: scripts/device_kernels.py). ~3 MB packed.
log=${TMPDIR:-/tmp}/softvr-device-kernels.log
$py scripts/device_kernels.py .whl/kernels-cache > "$log" 2>&1 || { tail -20 "$log"; exit 1; }
tar czf .whl/dl/kernels.tgz --exclude='*.cu' -C .whl kernels-cache
rm -rf .whl/kernels-cache
# The small wheels and the kernels (and with --vtk the head CT) with the last part where they fit
# under ~52 MB, else in a folder of their own; the MANIFEST goes last.
if [ "${1:-}" = "--vtk" ]; then
    k=$((k + 1)); mkdir -p ".whl/$k"
    cp "$($py -c "from softvr.datasets import HEAD_CT_PATH, data_file; print(data_file(HEAD_CT_PATH, 'invesalius-examples'))")" ".whl/$k/"
fi
if [ $(( $(du -sm ".whl/$k" | cut -f1) + $(du -smc .whl/dl/* | tail -1 | cut -f1) )) -gt 52 ]; then
    k=$((k + 1)); mkdir -p ".whl/$k"
fi
mv .whl/dl/*.whl .whl/dl/kernels.tgz ".whl/$k/"
rmdir .whl/dl
# What device_check.sh waits for before it installs: every part and file, by name.
(cd .whl && ls */* | sed 's|^[0-9]*/||' | grep -v '^MANIFEST$' > "$k/MANIFEST")
echo "carry these, one a call, in order (then the last call runs the checks):"
du -sh .whl/*
