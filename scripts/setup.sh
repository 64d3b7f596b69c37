#!/usr/bin/env bash
# Sets up everything mi_nest needs, idempotently: system libraries, then a
# virtual environment in .venv with mi_nest (editable) and its test tools.
set -euo pipefail
cd "$(dirname "$0")/.."

# Dr.Jit 1.5's LLVM backend needs LLVM 19 (15/16 crash it, 14 is refused).
if ! ls /usr/lib/*-linux-gnu/libLLVM-19.so >/dev/null 2>&1; then
    if command -v apt-get >/dev/null 2>&1; then
        SUDO=""
        if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
        echo "setup: installing libllvm19 (Dr.Jit's LLVM backend) with apt-get"
        $SUDO apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libllvm19 >/dev/null
    else
        echo "setup: LLVM 19 not found and no apt-get here: install libLLVM 19 and set" \
             "DRJIT_LIBLLVM_PATH to it" >&2
        exit 1
    fi
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
