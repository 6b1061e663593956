#!/usr/bin/env bash
# Runs the libFuzzer targets of a fuzz build (docs/fuzzing.md).
#
#   server/fuzz/run.sh regress BUILD          every corpus file once (regress-* included); fails on any crash
#   server/fuzz/run.sh fuzz BUILD SECONDS     each target for SECONDS, FUZZ_JOBS (2) at a time
#
# BUILD is a build directory configured with -DFLOWCLIP_FUZZ=ON (make fuzz-build:
# build-fuzz). TARGETS="scene_parser rest_request" limits the targets. Fuzzing
# reads server/fuzz/corpus/<target>/ and writes new inputs to BUILD/fuzz-corpus/<target>/ (or $FUZZ_SCRATCH/<target>/)
# (never into the repository), crash inputs to BUILD/fuzz-artifacts/<target>/, the
# log to BUILD/fuzz-logs/<target>.log, and prints one line of figures per target.
# A target's dictionary is server/fuzz/<target>.dict followed by BUILD/fuzz/make_fuzz_dict's
# declared parameters and methods (BUILD/fuzz-dicts/<target>.dict).
# Exit status: 0 when nothing crashed.
set -uo pipefail
cd "$(dirname "$0")/../.."
mode=${1:?usage: run.sh regress|fuzz BUILD [SECONDS]}
build=${2:?usage: run.sh regress|fuzz BUILD [SECONDS]}
seconds=${3:-60}
jobs=${FUZZ_JOBS:-2}
# Per input: a slower one is reported as a timeout (a finding).
timeout=${FUZZ_TIMEOUT:-25}
rss=${FUZZ_RSS_MB:-2048}
max_len=${FUZZ_MAX_LEN:-16384}
corpus_root=server/fuzz/corpus
# New inputs accumulate here across runs; FUZZ_SCRATCH (make test: a fresh
# folder) keeps a run's start-up from loading every earlier run's inputs.
scratch_root=${FUZZ_SCRATCH:-$build/fuzz-corpus}

targets=()
if [ -n "${TARGETS:-}" ]; then
  targets=($TARGETS)
else
  for bin in "$build"/fuzz/fuzz_*; do
    [ -x "$bin" ] && targets+=("$(basename "$bin" | sed 's/^fuzz_//')")
  done
fi
if [ ${#targets[@]} -eq 0 ]; then
  echo "fuzz: no targets in $build/fuzz (build them: make fuzz-build)" >&2
  exit 2
fi
logs="$build/fuzz-logs"
mkdir -p "$logs"
export ASAN_OPTIONS="${ASAN_OPTIONS:-}${ASAN_OPTIONS:+:}abort_on_error=0:handle_abort=1"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1}"
# Leaks inside third-party libraries, each with its reason.
export LSAN_OPTIONS="${LSAN_OPTIONS:-suppressions=$(pwd)/server/fuzz/sanitizers/lsan-fuzz.supp:print_suppressions=0}"

# The first stack frame inside server/ (not the harness): "function file:line".
crash_site() {
  local site
  grep -aq '^==FUZZ CHECK FAILED==' "$1" && return  # a property, not a place
  site=$(grep -aE '^ *#[0-9]+ 0x[0-9a-f]+ in ' "$1" | grep '/server/' | grep -v '/server/fuzz/' | head -1 |
    sed -E 's/^ *#[0-9]+ 0x[0-9a-f]+ in //; s/\(.*\)//; s#[^ ]*/server/#server/#')
  echo "at ${site:-(no frame in server/)}"
}
crash_kind() {
  if grep -aq '^==FUZZ CHECK FAILED==' "$1"; then
    # the check, then the first line of what was wrong
    grep -a -A1 -m1 '^==FUZZ CHECK FAILED==' "$1" | sed -E 's/^==FUZZ CHECK FAILED== [^ ]*\/server\//server\//' |
      paste -sd' ' | cut -c1-300
  else
    grep -a -m1 -E '^(SUMMARY: |==[0-9]+==ERROR: libFuzzer|terminate called|.*runtime error:)' "$1" |
      sed -E 's/^SUMMARY: //; s/ \(\/[^)]*\)//g; s/ \(BuildId: [0-9a-f]*\)//' | cut -c1-200
  fi
}

regress_one() {  # target -> status
  local t=$1 bin="$build/fuzz/fuzz_$1" dir="$corpus_root/$1" log="$logs/$1-regress.log"
  if [ ! -d "$dir" ]; then
    echo "regress $t: no corpus ($dir)"
    return 0
  fi
  local n
  n=$(find "$dir" -maxdepth 1 -type f | wc -l)
  local start=$SECONDS
  if "$bin" -runs=0 -timeout="$timeout" -rss_limit_mb="$rss" "$dir" >"$log" 2>&1; then
    echo "regress $t: $n inputs, no crash ($((SECONDS - start)) s)"
    return 0
  fi
  # Which ones: each file alone (a crash ends a run).
  echo "regress $t: CRASH; each input alone:"
  local f failed=0
  for f in "$dir"/*; do
    if ! "$bin" -timeout="$timeout" -rss_limit_mb="$rss" "$f" >"$log.one" 2>&1; then
      failed=$((failed + 1))
      echo "  FAIL $(basename "$f"): $(crash_kind "$log.one") $(crash_site "$log.one")"
      cp "$log.one" "$logs/$1-regress-$(basename "$f").log"
    fi
  done
  rm -f "$log.one"
  echo "regress $t: $failed of $n inputs crash (logs: $logs/$t-regress-*.log)"
  return 1
}

fuzz_one() {  # target -> status; figures on one line
  local t=$1 bin="$build/fuzz/fuzz_$1" log="$logs/$1.log"
  local scratch="$scratch_root/$t" art="$build/fuzz-artifacts/$t/"
  mkdir -p "$scratch" "$art"
  local dict=()
  if [ -f "server/fuzz/$t.dict" ]; then
    # The hand-written structure, then the declared parameters and methods.
    local merged="$build/fuzz-dicts/$t.dict"
    mkdir -p "$build/fuzz-dicts"
    cat "server/fuzz/$t.dict" >"$merged"
    [ -x "$build/fuzz/make_fuzz_dict" ] && "$build/fuzz/make_fuzz_dict" >>"$merged"
    dict=(-dict="$merged")
  fi
  local seeds=()
  [ -d "$corpus_root/$t" ] && seeds=("$corpus_root/$t")
  nice "$bin" -max_total_time="$seconds" -timeout="$timeout" -rss_limit_mb="$rss" -max_len="$max_len" \
    -print_final_stats=1 -artifact_prefix="$art" "${dict[@]}" "$scratch" "${seeds[@]}" >"$log" 2>&1
  local status=$?
  local done_line execs rate
  done_line=$(grep -aE '^#[0-9]+[[:space:]]+(DONE|NEW|REDUCE|pulse|INITED)' "$log" | tail -1)
  execs=$(sed -nE 's/^stat::number_of_executed_units: *//p' "$log")
  rate=$(sed -nE 's/^stat::average_exec_per_sec: *//p' "$log")
  [ -z "$execs" ] && execs=$(echo "$done_line" | sed -nE 's/^#([0-9]+).*/\1/p')
  local cov ft corp
  cov=$(echo "$done_line" | sed -nE 's/.* cov: ([0-9]+).*/\1/p')
  ft=$(echo "$done_line" | sed -nE 's/.* ft: ([0-9]+).*/\1/p')
  corp=$(echo "$done_line" | sed -nE 's/.* corp: ([0-9]+\/[0-9]+[a-zA-Z]*).*/\1/p')
  local result="no crash"
  if [ $status -ne 0 ]; then
    result="CRASH: $(crash_kind "$log") $(crash_site "$log"); input: $(ls -t "$art" 2>/dev/null | head -1 | sed "s#^#$art#")"
  fi
  echo "fuzz $t: ${seconds} s, ${execs:-?} execs (${rate:-?}/s), cov ${cov:-?}, ft ${ft:-?}, corpus ${corp:-?}: $result"
  return $status
}

status=0
case "$mode" in
  regress)
    for t in "${targets[@]}"; do regress_one "$t" || status=1; done
    ;;
  fuzz)
    # FUZZ_JOBS targets at a time; each prints its line when done.
    for t in "${targets[@]}"; do
      rm -f "$logs/$t.status"
      { fuzz_one "$t"; echo $? >"$logs/$t.status"; } &
      while [ "$(jobs -rp | wc -l)" -ge "$jobs" ]; do sleep 1; done
    done
    wait
    for t in "${targets[@]}"; do [ "$(cat "$logs/$t.status" 2>/dev/null)" = 0 ] || status=1; done
    ;;
  *)
    echo "run.sh: unknown mode '$mode' (regress or fuzz)" >&2
    exit 2
    ;;
esac
exit $status
