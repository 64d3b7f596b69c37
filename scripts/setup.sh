#!/usr/bin/env bash
# Sets up everything mi_nest needs, idempotently: system libraries, then a
# virtual environment in .venv with mi_nest (editable) and its test tools.
set -euo pipefail
cd "$(dirname "$0")/.."

# Usage: setup.sh [--browser]; --browser also installs Debian's chromium, which the viewer's test drives.
BROWSER=0
for argument in "$@"; do
    case "$argument" in
        --browser) BROWSER=1 ;;
        *) echo "setup: unknown option '$argument' (the only one is --browser)" >&2; exit 2 ;;
    esac
done

apt_install() {     # apt_install WHY PACKAGE...
    local why="$1"; shift
    if ! command -v apt-get >/dev/null 2>&1; then
        echo "setup: $why: no apt-get here; install $* yourself" >&2
        exit 1
    fi
    local sudo=""
    if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
    echo "setup: installing $* ($why) with apt-get"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "$@" >/dev/null
}

# Dr.Jit 1.5's LLVM backend needs LLVM 19 (15/16 crash it, 14 is refused).
if ! ls /usr/lib/*-linux-gnu/libLLVM-19.so >/dev/null 2>&1; then
    apt_install "Dr.Jit's LLVM backend; or set DRJIT_LIBLLVM_PATH to a libLLVM 19" libllvm19
fi
# The viewer's test runs in a real browser from the system's packages (none is downloaded at run time).
if [ "$BROWSER" = 1 ] && ! command -v chromium >/dev/null 2>&1; then
    apt_install "the viewer's browser test" chromium
fi

PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv"
    "$PYTHON" -m venv .venv
fi

# Reinstall only when the package metadata changed since the last install.
stamp=.venv/.mi_nest-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    echo "setup: installing mi_nest and its dependencies into .venv"
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[test]"
    touch "$stamp"
fi
