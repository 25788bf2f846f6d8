#!/usr/bin/env bash
# The README's test command: set up a virtual environment and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null || PY=python3
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --disable-pip-version-check -e '.[test]'
# Tests that need system packages: the live view's page in a real headless browser
# (tests/test_live.py) and MuJoCo's offscreen pictures (EGL: the env's render modes, the report's
# picture). As root, install what is missing from Debian; the tests skip, saying why, where this
# cannot be done.
missing=()
command -v chromium >/dev/null || missing+=(chromium)
ldconfig -p 2>/dev/null | grep -q 'libEGL_mesa\.so' || missing+=(libegl1 libegl-mesa0)
if [ ${#missing[@]} -gt 0 ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null) \
    || echo "scripts/test.sh: could not install ${missing[*]}; the tests that need them will skip" >&2
fi
# The type check first (pyproject.toml's [tool.mypy]: twin/ and envs/; any error fails the run).
.venv/bin/python -m mypy
# Two workers (pytest-xdist): the suite is bound by one core per twin or fit, and CI has two.
exec .venv/bin/python -m pytest -q -n 2 "$@"
