#!/usr/bin/env bash
# The whole test suite in two parts, as `make test` and CI run it (arguments go to both pytest runs).
#
# First every test not marked `timing`, on two workers (pytest-xdist: most tests wait on processes,
# sockets or a browser); then the `timing` tests alone, so no rate or latency is judged while
# another test loads the cores. Both parts always run; the exit status is the first failure's.
set -u
cd "$(dirname "$0")/.."
py=.venv/bin/python
"$py" -m pytest -n 2 -m "not timing" "$@"; first=$?
"$py" -m pytest -m timing "$@"; second=$?
# pytest's 5 is "no test selected": a part that a selection (a file, -k) leaves empty is no failure
fine() { [ "$1" -eq 0 ] || [ "$1" -eq 5 ]; }
fine "$first" || exit "$first"
fine "$second" || exit "$second"
if [ "$first" -eq 5 ] && [ "$second" -eq 5 ]; then exit 5; fi
exit 0
