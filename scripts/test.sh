#!/usr/bin/env bash
# The README's test command: set up a virtual environment and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null || PY=python3
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --disable-pip-version-check -e '.[test]'
# The live view's test opens its page in a real headless browser (tests/test_live.py); as root,
# install Debian's Chromium when it is missing (the test skips, saying why, where this cannot be done).
if ! command -v chromium >/dev/null && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
    || echo "scripts/test.sh: could not install chromium; the browser test of the live view will skip" >&2
fi
# Two workers (pytest-xdist): the suite is bound by one core per twin or fit, and CI has two.
exec .venv/bin/python -m pytest -q -n 2 "$@"
