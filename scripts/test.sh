#!/usr/bin/env bash
# Sets everything up, then runs the test suite (fast tests; add "-m slow" for the slow ones).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh --browser
# Two processes, each a test file at a time (its fixtures built once, its tests in order): much of a test is
# single-threaded (tracing, compiling kernels, Python), so two interleave on 2 cores; Dr.Jit's kernels use every
# core in either. "-n 0" after the script's name runs in one process.
exec .venv/bin/python -m pytest -n 2 --dist loadfile "$@"
