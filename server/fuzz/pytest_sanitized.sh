#!/usr/bin/env bash
# The pytest suite (tests/) against a sanitized flowclip (docs/fuzzing.md):
#
#   server/fuzz/pytest_sanitized.sh BUILD PYTHON [pytest args...]
#
# BUILD holds a flowclip built with -DFLOWCLIP_SANITIZE=ON (make asan-build:
# build-asan). Every sanitizer report of every flowclip process the tests
# start (servers, `flowclip run`, `bench`, `record`) goes to
# BUILD/sanitizer-logs/ instead of the process's stderr, so that no report
# is lost in a test that expects a failing exit status; any report fails
# this script, after pytest's own summary line, and is printed.
set -uo pipefail
cd "$(dirname "$0")/../.."
build=$(cd "${1:?usage: pytest_sanitized.sh BUILD PYTHON [pytest args]}" && pwd)
python=${2:?usage: pytest_sanitized.sh BUILD PYTHON [pytest args]}
shift 2
logs="$build/sanitizer-logs"
rm -rf "$logs"
mkdir -p "$logs"
supp="$(pwd)/server/fuzz/sanitizers"

export FLOWCLIP_BIN="$build/flowclip"
# Tests that measure memory (RSS) skip themselves under the sanitizers.
export FLOWCLIP_SANITIZED=1
# `flowclip bench accuracy` plots with the venv beside the binary (BUILD/venv):
# the test venv's.
venv=$(cd "$(dirname "$python")/.." && pwd)
[ -e "$build/venv" ] || [ "$venv" = "$build/venv" ] || ln -s "$venv" "$build/venv"
# halt_on_error: the first UB report ends the process (the report is in the
# log; the test then fails on the exit status or the dead server).
export ASAN_OPTIONS="log_path=$logs/asan:detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=0:check_initialization_order=1"
export UBSAN_OPTIONS="log_path=$logs/ubsan:halt_on_error=1:print_stacktrace=1:suppressions=$supp/ubsan.supp"
export LSAN_OPTIONS="suppressions=$supp/lsan.supp:print_suppressions=0"

start=$SECONDS
# Tests marked heavy are left out: minutes of simulation each under the sanitizers (tests/conftest.py).
"$python" -m pytest -q -m "not heavy" "$@" tests
status=$?
elapsed=$((SECONDS - start))

reports=$(find "$logs" -type f | sort)
if [ -n "$reports" ]; then
  echo "sanitizers: $(echo "$reports" | wc -l) report(s) from flowclip processes (in $logs):"
  for r in $reports; do
    echo "---- $r"
    head -n 60 "$r"
  done
  status=1
else
  echo "sanitizers: no ASan/UBSan/LSan report from any flowclip process (${elapsed} s)"
fi
exit $status
