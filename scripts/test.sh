#!/usr/bin/env bash
# The README's test command: set up a virtual environment and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null || PY=python3
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --disable-pip-version-check -e '.[test]'
# Two workers (pytest-xdist): the suite is bound by one core per twin or fit, and CI has two.
exec .venv/bin/python -m pytest -q -n 2 "$@"
