#!/usr/bin/env bash
# Builds mi_nest's wheel, installs it (not editable) into a fresh virtual environment
# outside the checkout, and runs the main job (mi-nest demo) from there: a module left
# out of the wheel fails here, not on a user's machine.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
echo "check_wheel: building the wheel"
.venv/bin/python -m pip wheel --no-deps -q -w "$work/wheel" . >/dev/null
"${PYTHON:-python3}" -m venv "$work/venv"
echo "check_wheel: installing it into a fresh environment in $work"
"$work/venv/bin/python" -m pip install -q "$work"/wheel/mi_nest-*.whl
cd "$work"   # the checkout is not on the path from here on
"$work/venv/bin/python" -c "import mi_nest, sys; assert 'site-packages' in mi_nest.__file__, mi_nest.__file__"
echo "check_wheel: running mi-nest demo from the installed wheel"
"$work/venv/bin/mi-nest" demo -o "$work/demo"
test -s "$work/demo/truth_vs_reconstructed.png"
echo "check_wheel: the installed wheel ran the demo"
