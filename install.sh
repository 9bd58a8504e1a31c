#!/usr/bin/env bash
# Install wearfit_usd and what it needs on a fresh Debian/Ubuntu machine, as root or as a sudo user.
#
#   ./install.sh              system packages, then the package (editable) into the Python chosen below
#   ./install.sh test [ARGS]  run the test suite with that same Python (ARGS go to pytest)
#   ./install.sh python ARGS  run that same Python (e.g. ./install.sh python -m ruff check .)
#
# System packages (apt, only those missing):
#   - libosmesa6 (+ libegl1, libgl1): offscreen OpenGL for previews (no GPU, no display)
#   - libsuitesparse-dev + libopenblas0-pthread + build-essential: CHOLMOD sparse Cholesky
#     (scikit-sparse has no wheel and builds here)
#   - python3.X-venv / python3.X-dev only when the venv module or Python.h is missing
#     (minimal Debian/Ubuntu images lack them; python3 itself if there is none)
# Which Python (PYTHON=/path/to/python overrides `python3`):
#   1. the virtualenv or conda env that python3 runs in, if any: installed there, nothing else made;
#   2. else this checkout's .venv, if there is one;
#   3. else python3 itself, if it allows pip installs (pyenv, a self-built Python, ...);
#   4. else (Debian 12 / Ubuntu 24.04's own Python is "externally managed", PEP 668, and refuses
#      pip installs) a new .venv in this checkout.
#   With 2 and 4 `wearfit` is linked onto PATH to .venv/bin/wearfit: ~/.local/bin/wearfit for a
#   user who has ~/.local/bin on PATH, else /usr/local/bin/wearfit (with sudo for a user).
# Then PyOpenGL 3.1.10: pyrender 0.1.45 pins PyOpenGL 3.1.0, which cannot create OSMesa contexts.
# Then, when npm exists, the Khronos glTF-Validator (npm gltf-validator) into .tools/ for the tests.
set -euo pipefail
cd "$(dirname "$0")"
ROOT="$PWD"
PYTHON="${PYTHON:-python3}"
VENV="$ROOT/.venv"

say() { echo "install.sh: $*"; }
die() { echo "install.sh: error: $*" >&2; exit 1; }

SUDO=""
if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi

APT_UPDATED=""
apt_install() {  # installs those of the given Debian packages that are not installed yet
    local missing=() p
    for p in "$@"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "ok installed" || missing+=("$p")
    done
    [ ${#missing[@]} -eq 0 ] && return 0
    command -v apt-get >/dev/null || die "no apt-get: install ${missing[*]} (or their equivalents) by hand"
    if [ -n "$SUDO" ] && ! command -v sudo >/dev/null; then
        die "not root and no sudo: run as root, or install ${missing[*]} first"
    fi
    say "apt-get install ${missing[*]}"
    if [ -z "$APT_UPDATED" ]; then $SUDO apt-get update -qq; APT_UPDATED=1; fi
    $SUDO env DEBIAN_FRONTEND=noninteractive \
        apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

pyq() { "$1" -c "$2" 2>/dev/null; }  # run a one-line Python query, quiet on failure

in_env() {  # is $1 running inside a virtualenv or a conda env?
    pyq "$1" 'import os, sys
c = os.environ.get("CONDA_PREFIX")
env = sys.prefix != sys.base_prefix or bool(c and os.path.realpath(c) == os.path.realpath(sys.prefix))
raise SystemExit(0 if env else 1)'
}

externally_managed() {  # does $1 refuse pip installs (PEP 668 marker, outside a venv)?
    pyq "$1" 'import os, sys, sysconfig
marker = os.path.join(sysconfig.get_path("stdlib"), "EXTERNALLY-MANAGED")
raise SystemExit(0 if sys.prefix == sys.base_prefix and os.path.isfile(marker) else 1)'
}

venv_ok() { [ -x "$VENV/bin/python" ] && pyq "$VENV/bin/python" 'import sys'; }

# choose_python: sets PY (the interpreter to install into / test with) and MODE (env|venv|python|new)
choose_python() {
    if in_env "$PYTHON"; then
        PY="$(pyq "$PYTHON" 'import sys; print(sys.executable)')"; MODE=env
    elif [ -e "$VENV" ]; then
        PY="$VENV/bin/python"; MODE=venv
    elif externally_managed "$PYTHON"; then
        PY="$VENV/bin/python"; MODE=new
    else
        PY="$(pyq "$PYTHON" 'import sys; print(sys.executable)')"; MODE=python
    fi
}

# ---------------------------------------------------------------- ./install.sh test | python
if [ "${1:-}" = "test" ] || [ "${1:-}" = "python" ]; then
    SUB="$1"; shift
    command -v "$PYTHON" >/dev/null || die "no $PYTHON: run ./install.sh first"
    choose_python
    if [ "$MODE" = new ]; then
        die "no .venv here and $PYTHON is not in a virtualenv: run ./install.sh first (or activate the environment it installed into)"
    fi
    NEED="wearfit_usd"
    if [ "$SUB" = test ]; then NEED="wearfit_usd, pytest"; set -- -m pytest -q "$@"; fi
    pyq "$PY" "import $NEED" || die "$NEED not installed for $PY: run ./install.sh first"
    [ "$SUB" = test ] && say "$PY $*"
    exec "$PY" "$@"
elif [ $# -gt 0 ]; then
    case "$1" in
        -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d' | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) die "unknown argument '$1' (usage: ./install.sh [test [PYTEST ARGS] | python ARGS | --help])" ;;
    esac
fi

# ---------------------------------------------------------------- ./install.sh
if ! command -v "$PYTHON" >/dev/null; then
    [ "$PYTHON" = python3 ] || die "no $PYTHON"
    apt_install python3 python3-venv python3-dev
fi
pyq "$PYTHON" 'import sys; raise SystemExit(sys.version_info < (3, 11))' ||
    die "$PYTHON is Python $(pyq "$PYTHON" 'import platform; print(platform.python_version())'); wearfit_usd needs >= 3.11 (PYTHON=/path/to/python3.11 ./install.sh)"
choose_python

MAKE_VENV=""
if [ "$MODE" = new ] || { [ "$MODE" = venv ] && ! venv_ok; }; then MAKE_VENV=1; fi
BASE="$PY"                             # the interpreter whose headers the build uses
[ -n "$MAKE_VENV" ] && BASE="$PYTHON"
VER="$(pyq "$BASE" 'import sys; print("%d.%d" % sys.version_info[:2])')"
SYSPKGS=(libosmesa6 libegl1 libgl1 libsuitesparse-dev libopenblas0-pthread build-essential)
if [ -n "$MAKE_VENV" ] && ! pyq "$PYTHON" 'import ensurepip'; then
    SYSPKGS+=("python$VER-venv")       # Debian/Ubuntu ship the venv module's pip apart
fi
if ! pyq "$BASE" 'import os, sysconfig
raise SystemExit(not os.path.isfile(os.path.join(sysconfig.get_path("include"), "Python.h")))'; then
    SYSPKGS+=("python$VER-dev")        # headers to build scikit-sparse
fi
apt_install "${SYSPKGS[@]}"

case "$MODE" in
    env)    say "installing into the active environment's Python: $PY" ;;
    python) say "installing into $PY" ;;
    venv|new)
        if [ "$MODE" = new ]; then
            say "$PYTHON is externally managed (PEP 668): making a virtualenv in $VENV"
        elif [ -n "$MAKE_VENV" ]; then
            say "$VENV does not run: making it again"
        fi
        [ -n "$MAKE_VENV" ] && "$PYTHON" -m venv --clear "$VENV"
        say "installing into $VENV" ;;
esac

PIP=("$PY" -m pip)
"${PIP[@]}" install -q --upgrade pip
"${PIP[@]}" install -e ".[fast,bench,test]"
# pip then reports the pin conflict on purpose ("pyrender 0.1.45 requires PyOpenGL==3.1.0"): expected.
"${PIP[@]}" install "PyOpenGL==3.1.10" 2>&1 | grep -v -e "pyrender 0.1.45 requires PyOpenGL==3.1.0" \
    -e "dependency resolver does not currently take into account" || true
"$PY" -c "import OpenGL; assert OpenGL.__version__ == '3.1.10', OpenGL.__version__"
"$PY" -c "import wearfit_usd, pxr, pyrender; print('wearfit_usd installed')"
# compile the numba kernels once now (cached beside the package), not on the first run
"$PY" -m wearfit_usd.kernels
# the Khronos glTF-Validator (a test checks `wearfit export` against it) into .tools/, when npm exists
if command -v npm >/dev/null; then
    mkdir -p "$ROOT/.tools"
    (cd "$ROOT/.tools" && npm install --no-audit --no-fund --silent gltf-validator@2.0.0-dev.3.10 >/dev/null) ||
        say "warning: npm could not install gltf-validator; the glTF validation test will not run"
else
    say "no npm: the glTF validation test will not run (apt-get install nodejs npm, then ./install.sh)"
fi
# byte-compile the package as pip does for regular installs (an editable install
# skips it; with PYTHONDONTWRITEBYTECODE set every run would compile it again)
"$PY" -m compileall -q wearfit_usd

# ---------------------------------------------------------------- the `wearfit` command on PATH
on_path() { case ":$PATH:" in *":$1:"*) return 0 ;; *) return 1 ;; esac; }
SCRIPT="$(pyq "$PY" 'import sysconfig; print(sysconfig.get_path("scripts"))')/wearfit"
if [ ! -x "$SCRIPT" ]; then  # pip falls back to a --user install where site-packages is read-only
    SCRIPT="$(pyq "$PY" 'import os, sysconfig; print(sysconfig.get_path("scripts", os.name + "_user"))')/wearfit"
fi
[ -x "$SCRIPT" ] || die "pip made no wearfit command for $PY"
LINK=""
if [ "$MODE" = venv ] || [ "$MODE" = new ]; then
    if [ "$(id -u)" != "0" ] && on_path "$HOME/.local/bin"; then
        LINK="$HOME/.local/bin/wearfit"; LSUDO=""
    else
        LINK="/usr/local/bin/wearfit"; LSUDO="$SUDO"
    fi
    if [ -e "$LINK" ] && [ ! -L "$LINK" ]; then
        say "warning: $LINK exists and is not a link: left as it is; this checkout's command is $SCRIPT"
        LINK=""
    else
        $LSUDO mkdir -p "$(dirname "$LINK")"
        $LSUDO ln -sfn "$SCRIPT" "$LINK"
        say "linked $LINK -> $SCRIPT"
    fi
fi
hash -r
FOUND="$(command -v wearfit || true)"
if [ -z "$FOUND" ]; then
    say "warning: \`wearfit\` is not on PATH; run $SCRIPT, or add $(dirname "${LINK:-$SCRIPT}") to PATH"
elif [ -n "$LINK" ] && [ "$FOUND" != "$LINK" ]; then
    say "warning: \`wearfit\` on PATH is $FOUND, which comes before $LINK; this checkout's command is $SCRIPT"
elif [ -z "$LINK" ] && [ "$FOUND" != "$SCRIPT" ] && [ "$(readlink -f "$FOUND")" != "$(readlink -f "$SCRIPT")" ] &&
        ! "$FOUND" --version >/dev/null 2>&1; then
    say "warning: \`wearfit\` on PATH is $FOUND, which does not run; this checkout's command is $SCRIPT"
fi
say "done: Python $PY; \`wearfit demo -o demo_out\` to try it, \`./install.sh test\` to run the tests"
