#!/usr/bin/env bash
# The timing-sensitive tests, 3 rounds in a row with 4 busy loops on the cores (issue 16).
# Options (see scripts/loaded_rounds.py --help): --rounds N --busy K --stop-on-failure -- PYTEST_ARGS
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
py="${PYTHON:-}"
if [ -z "$py" ]; then
    if [ -x "$here/.venv/bin/python" ]; then py="$here/.venv/bin/python"; else py="python3"; fi
fi
exec "$py" "$here/scripts/loaded_rounds.py" "$@"
