#!/usr/bin/env bash
# Install wearfit_usd and what it needs on a fresh Debian/Ubuntu machine.
#   - libosmesa6: offscreen OpenGL for previews (no GPU, no display)
#   - libsuitesparse-dev + libopenblas0-pthread: CHOLMOD sparse Cholesky (fast body fitting)
# Then the Python package (editable) with the fast solver, tests and peers used by the benchmarks,
# and PyOpenGL 3.1.10: pyrender 0.1.45 pins PyOpenGL 3.1.0, which cannot create OSMesa contexts.
set -euo pipefail
cd "$(dirname "$0")"
SUDO=""
if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
    libosmesa6 libegl1 libgl1 libsuitesparse-dev libopenblas0-pthread build-essential >/dev/null
PIP="${PIP:-python3 -m pip}"
$PIP install --upgrade pip >/dev/null
$PIP install -e ".[fast,bench,test]"
# pip then reports the pin conflict on purpose ("pyrender 0.1.45 requires PyOpenGL==3.1.0"): expected.
$PIP install "PyOpenGL==3.1.10" 2>&1 | grep -v -e "pyrender 0.1.45 requires PyOpenGL==3.1.0" \
    -e "dependency resolver does not currently take into account" || true
python3 -c "import OpenGL; assert OpenGL.__version__ == '3.1.10', OpenGL.__version__" 
python3 -c "import wearfit_usd, pxr, pyrender; print('wearfit_usd installed')"
# compile the numba kernels once now (cached beside the package), not on the first run
python3 -m wearfit_usd.kernels
# byte-compile the package as pip does for regular installs (an editable install
# skips it; with PYTHONDONTWRITEBYTECODE set every run would compile it again)
python3 -m compileall -q wearfit_usd
