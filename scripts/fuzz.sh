#!/usr/bin/env bash
# Builds formloop's libFuzzer targets (fuzz/) under AddressSanitizer + UndefinedBehaviorSanitizer in a separate
# clang build folder (scripts/sanitizer_build.sh) and runs each for a given time.
#
#   scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET ...]     default 60 s, every target
#   FORMLOOP_FUZZ_PARALLEL=2 scripts/fuzz.sh 480          two targets at a time
#   FORMLOOP_FUZZ_NO_BUILD=1 scripts/fuzz.sh 60 T         run what is built (e.g. while the folder builds more)
#
# Each target starts from its seed corpus fuzz/corpus/<target>/ (read only) and keeps what it finds in
# <build>/fuzz-out/corpus/<target>/; a crash, hang (-timeout) or sanitizer report leaves its input in
# <build>/fuzz-out/artifacts/ and fails the run. Copy such an input into fuzz/corpus/<target>/ with the fix,
# so the seed corpus replays it. At the end a table gives each target's time, executions and result
# (also in <build>/fuzz-out/summary.tsv).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/sanitizer_build.sh"

SECONDS_PER_TARGET="${1:-60}"
shift || true
ALL_TARGETS=(fuzz_points_csv fuzz_points_xyz fuzz_points_ply fuzz_points_pcd fuzz_probe_log fuzz_part_json
             fuzz_model_json fuzz_case_json fuzz_gcode fuzz_step fuzz_iges)
TARGETS=("$@")
((${#TARGETS[@]})) || TARGETS=("${ALL_TARGETS[@]}")
PARALLEL="${FORMLOOP_FUZZ_PARALLEL:-1}"
OUT="$SAN_BUILD/fuzz-out"

san_configure
[[ -n "${FORMLOOP_FUZZ_NO_BUILD:-}" ]] || cmake --build "$SAN_BUILD" --parallel "$SAN_JOBS" --target "${TARGETS[@]}"
mkdir -p "$OUT/logs" "$OUT/artifacts"

run_one() {
  local t="$1"
  mkdir -p "$OUT/corpus/$t"
  local start end rc=0
  start=$(date +%s)
  "$SAN_BUILD/fuzz/$t" -max_total_time="$SECONDS_PER_TARGET" -timeout=20 -rss_limit_mb=2560 -max_len=65536 \
    -print_final_stats=1 -artifact_prefix="$OUT/artifacts/$t-" \
    "$OUT/corpus/$t" "$ROOT/fuzz/corpus/$t" >"$OUT/logs/$t.log" 2>&1 || rc=$?
  end=$(date +%s)
  local execs
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$OUT/logs/$t.log" | tail -1)
  printf '%s\t%s\t%s\t%s\n' "$t" "$((end - start))" "${execs:-?}" "$([[ $rc == 0 ]] && echo ok || echo "FAILED rc=$rc")"
}
export -f run_one
export OUT SAN_BUILD ROOT SECONDS_PER_TARGET

printf '%s\n' "${TARGETS[@]}" | xargs -P "$PARALLEL" -I{} bash -c 'run_one {}' | tee "$OUT/summary.run.tsv"
cat "$OUT/summary.run.tsv" >>"$OUT/all-runs.tsv"  # every invocation, for the totals per target
{
  printf 'target\tseconds\texecutions\tresult\n'
  sort "$OUT/summary.run.tsv"
} >"$OUT/summary.tsv"
column -t -s $'\t' "$OUT/summary.tsv"
if grep -q FAILED "$OUT/summary.run.tsv"; then
  echo "fuzzing found something: see $OUT/logs and $OUT/artifacts" >&2
  exit 1
fi
