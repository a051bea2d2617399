#!/usr/bin/env bash
# Set up softvr on a fresh Debian (12+) machine and run a job:
#   bash scripts/setup.sh demo   install everything, run `softvr demo` on the bundled head CT
#   bash scripts/setup.sh test   install everything, run the whole test suite
#   bash scripts/setup.sh docs   install everything and the docs extra, build the docs site into docs/_build/html
#                                (warnings are errors; the gallery's images are scripts/gallery.py's, committed)
# Installs Debian packages (offline datasets, EGL/Mesa for offscreen rendering, Xvfb) and a
# virtual environment in .venv with softvr and its Python dependencies.
set -euo pipefail
cd "$(dirname "$0")/.."
job="${1:-test}"; shift || true

APT_PACKAGES=(python3 python3-venv python3-pip invesalius-examples mricron-data
              libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 libgl1 libglx-mesa0 libx11-6 libxrender1
              libxcursor1 libxt6 xvfb xauth)
missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "setup: installing Debian packages: ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PY="${PYTHON:-python3}"
"$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' || { echo "setup: softvr needs Python >= 3.11 ($PY is older)"; exit 1; }
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
stamp=.venv/.softvr-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "setup: installing softvr and its Python dependencies into .venv"
  .venv/bin/pip install -q --upgrade pip
  .venv/bin/pip install -q -e ".[dev]"
  touch "$stamp"
fi
# The docs tools for `docs`, and for `test` too: the suite builds the docs site with warnings as errors
# (tests/test_docs_build.py, ~30 s), so CI catches a docstring or page that breaks it.
if [ "$job" = docs ] || [ "$job" = test ]; then
  docs_stamp=.venv/.softvr-docs-installed
  if [ ! -f "$docs_stamp" ] || [ pyproject.toml -nt "$docs_stamp" ]; then
    echo "setup: installing the docs tools (softvr[docs]) into .venv"
    .venv/bin/pip install -q -e ".[dev,docs]"
    touch "$docs_stamp"
  fi
fi

# Blender as a Python module (bpy 4.2, CPython 3.11 only, ~0.5 GB) for the test that exports a
# scene with Blender's own glTF exporter; in its own environment, apart from softvr's.
if [ "$job" = test ] && "$PY" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
  if [ ! -f .venv-blender/.bpy-installed ]; then
    echo "setup: installing Blender's Python module (bpy 4.2) into .venv-blender"
    "$PY" -m venv .venv-blender
    .venv-blender/bin/pip install -q "bpy==4.2.*"
    touch .venv-blender/.bpy-installed
  fi
fi

case "$job" in
  demo) exec .venv/bin/python -m softvr demo "$@" ;;
  # With no arguments, the physics folders run a second time in what a CUDA step does, on the CPU:
  # through host copies, with the kernels' GPU forms, their thread blocks' lanes as Warp's
  # cooperative fibers (docs/physics-core.md, "The device", "The contact step in one block").
  test) .venv/bin/python -m pytest -q "$@"
        if [ $# -eq 0 ]; then
          echo "setup: the physics tests again through host copies with the kernels' GPU forms and blocks"
          .venv/bin/python -m pytest -q --host-copies --gpu-forms --cpu-blocks tests/dynamics tests/contact \
            tests/haptics tests/collision tests/sim tests/model tests/scene
        fi ;;
  # -E: a fresh environment every time, so a clean clone and a rebuild see the same warnings.
  docs) .venv/bin/python -m sphinx -W --keep-going -E -q -b html docs docs/_build/html "$@"
        echo "docs: docs/_build/html/index.html" ;;
  *) echo "usage: bash scripts/setup.sh demo|test|docs [args]"; exit 2 ;;
esac
