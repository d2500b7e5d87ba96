#!/usr/bin/env bash
# Run the lint gate (ruff.toml: pyflakes, pycodestyle, import order, public docstrings), then the whole
# suite (every package's tests and the cross-package tests in test/).
# pytest exit code 5 (no tests collected) is a failure here, never a silent pass.
set -uo pipefail
cd "$(dirname "$0")/.."
if ! .venv/bin/ruff check --quiet .; then
  echo "run_tests: ruff check . failed (fix the lines above, or .venv/bin/ruff check --fix . for imports)" >&2
  exit 1
fi
.venv/bin/python -m pytest -p no:cacheprovider "$@"
code=$?
if [ "$code" = 5 ]; then
  echo "run_tests: pytest collected no tests; that is a failure" >&2
  exit 1
fi
exit "$code"
