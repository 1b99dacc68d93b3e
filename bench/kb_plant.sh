#!/bin/sh
# A plant's shared case library on PostgreSQL, measured (issue 28): concurrency, a server lost mid-batch,
# and batch wall time with --jobs 1 / 2. Starts its own PostgreSQL server (tests/kb/postgres_server.sh)
# and stops it at the end. Long: run it nice'd, by hand, not in CI.
#
#   bench/kb_plant.sh BUILD_DIR [WORK_DIR]      e.g. nice -n 10 bench/kb_plant.sh build
#   FORMLOOP_PLANT_STAGES="fault batch" bench/kb_plant.sh build    only some of: adds retain fault batch
#
# Prints one line per figure:
#   adds        8 processes x 250 `formloop kb add` into one library: cases, kb check, GHSOM state
#   retain      4 parts in 4 processes (`run --jobs 4`) retaining into one library: cases, learned models
#   fault       the server stopped (pg_ctl stop -m fast) while 2 parts run: their errors; library state
#   rerun       the server restarted, the batch run again: parts within tolerance, cases
#   batch       16 parts with --jobs 1 and --jobs 2: wall time
set -eu
build=$(cd "${1:?usage: kb_plant.sh BUILD_DIR [WORK_DIR]}" && pwd)
work=${2:-$(mktemp -d /tmp/formloop-kb-plant.XXXXXX)}
src=$(cd "$(dirname "$0")/.." && pwd)
formloop="$build/app/formloop"
server="$src/tests/kb/postgres_server.sh"
pgdir="$work/postgres"
bin=/usr/lib/postgresql/15/bin
mkdir -p "$work"
sh "$server" start "$pgdir"
trap 'sh "$server" stop "$pgdir"' EXIT
base=$(cat "$pgdir/url")
as_server_user() { if [ "$(id -u)" = 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi; }
psql_c() { /usr/bin/psql -q -t -A "$base" -c "$1"; }
library() {  # a fresh schema -> its library URL
  psql_c "CREATE SCHEMA $1;" >/dev/null
  echo "$base?options=-csearch_path%3D$1"
}
count() { "$formloop" kb stats "$1" 2>/dev/null | python3 -c 'import json,sys; print(json.load(sys.stdin)["cases"])'; }

stages=${FORMLOOP_PLANT_STAGES:-adds retain fault batch}
want() { case " $stages " in *" $1 "*) return 0 ;; esac; return 1; }
mkdir -p "$work/parts4" "$work/parts16"
python3 - "$src/data/parts/demo-saddle.json" "$work" <<'PY'
import json, sys
part = json.load(open(sys.argv[1]))
for n, folder in ((4, "parts4"), (16, "parts16")):
    for i in range(n):
        p = dict(part)
        p["name"] = "plant-saddle-%02d" % i
        p["seed"] = part["seed"] + i
        json.dump(p, open("%s/%s/%s.json" % (sys.argv[2], folder, p["name"]), "w"), indent=1)
PY

# ---- 8 processes x 250 kb add
if want adds; then
kb=$(library adds)
"$formloop" kb init "$kb" --starter >/dev/null 2>&1
before=$(count "$kb")
python3 - "$src/data/kb/example_case.json" "$work/cases" <<'PY'
import json, os, sys
case = json.load(open(sys.argv[1]))
os.makedirs(sys.argv[2], exist_ok=True)
for w in range(8):
    for i in range(250):
        c = dict(case)
        c["uid"] = "plant-w%d-%03d" % (w, i)
        c["descriptor"] = [v * (1 + 0.001 * ((w * 250 + i) % 17)) for v in case["descriptor"]]
        json.dump(c, open(os.path.join(sys.argv[2], "w%d-%03d.json" % (w, i)), "w"))
PY
start=$(date +%s.%N)
for w in 0 1 2 3 4 5 6 7; do
  (for f in "$work"/cases/w$w-*.json; do "$formloop" kb add "$kb" "$f" >/dev/null 2>>"$work/adds-w$w.log" || echo "FAILED $f" >>"$work/adds-failed.log"; done) &
done
wait
end=$(date +%s.%N)
after=$(count "$kb")
check=$("$formloop" kb check "$kb" 2>/dev/null | python3 -c 'import json,sys; r=json.load(sys.stdin); g=r["ghsom"]; print("clean" if not r["problems"] else "NOT CLEAN %s" % r["problems"], "ghsom_stale=%s" % g.get("stale"), "ghsom_cases=%s" % g.get("case_count"))')
echo "adds: 8 x 250 kb add: cases $before -> $after (+$((after - before))), failed adds: $(cat "$work/adds-failed.log" 2>/dev/null | wc -l), kb check: $check, wall $(python3 -c "print(round($end - $start, 1))") s"

fi

# ---- 4 parallel retain steps
if want retain; then
kb=$(library retain)
"$formloop" kb init "$kb" --starter >/dev/null 2>&1
before=$(count "$kb")
"$formloop" run "$work/parts4" --kb "$kb" --jobs 4 --no-report --out "$work/retain" >/dev/null 2>"$work/retain.log" || true
after=$(count "$kb")
python3 - "$work/retain" "$formloop" "$kb" <<'PY'
import json, subprocess, sys
batch = json.load(open(sys.argv[1] + "/batch_summary.json"))
uids, learned = [], 0
for row in batch["parts"]:
    r = json.load(open(row["run_folder"] + "/retain.json"))
    uids.append(r["uid"])
    learned += r["learned_model"] is not None
present = 0
for uid in uids:
    out = subprocess.run([sys.argv[2], "kb", "show", sys.argv[3], uid], capture_output=True, text=True)
    present += out.returncode == 0 and json.loads(out.stdout).get("uid") == uid
check = json.loads(subprocess.run([sys.argv[2], "kb", "check", sys.argv[3]], capture_output=True, text=True).stdout)
print("retain: 4 parts --jobs 4: %d ok / %d failed; retained cases present %d/%d; learned models in retain.json %d/4; "
      "kb check %s, GHSOM stale=%s cases=%s" % (batch["within_tolerance"] + batch["out_of_tolerance"], batch["failed"],
      present, len(uids), learned, "clean" if not check["problems"] else check["problems"], check["ghsom"].get("stale"),
      check["ghsom"].get("case_count")))
PY

fi

# ---- the server stopped in the middle of a batch
if want fault; then
kb=$(library fault)
"$formloop" kb init "$kb" --starter >/dev/null 2>&1
before=$(count "$kb")
audit_before=$(psql_c "SELECT count(*) FROM fault.audit;")
(set +e; "$formloop" run "$work/parts4" --kb "$kb" --jobs 2 --no-report --out "$work/fault" >/dev/null 2>"$work/fault.log"; echo $? >"$work/fault.rc") &
runner=$!
# Stop the server once the first retain step is under way or 4 s into the batch, whichever comes later.
sleep 4
as_server_user "$bin/pg_ctl" -D "$pgdir/data" -m fast -w stop >/dev/null
wait $runner || true
python3 - "$work/fault" <<'PY'
import json, sys
b = json.load(open(sys.argv[1] + "/batch_summary.json"))
errors = [row.get("error", "") for row in b["parts"] if row["status"] == "failed"]
import os
print("fault: exit %s; %d of %d parts failed; first error: %s" % (open(os.path.dirname(sys.argv[1]) + "/fault.rc").read().strip(),
      len(errors), b["count"], errors[0] if errors else "-"))
PY
port=$(echo "$base" | sed 's|.*:\([0-9]*\)/.*|\1|')
as_server_user "$bin/pg_ctl" -D "$pgdir/data" -l "$pgdir/server.log" -w \
  -o "-p $port -k $pgdir -c listen_addresses=127.0.0.1 -c fsync=off -c synchronous_commit=off" start >/dev/null
after=$(count "$kb")
check=$("$formloop" kb check "$kb" 2>/dev/null | python3 -c 'import json,sys; r=json.load(sys.stdin); print("clean" if not r["problems"] else r["problems"])')
partial=$(ls -d "$work"/fault/*.partial 2>/dev/null | wc -l)
echo "fault: library after the stop: cases $before -> $after, kb check $check; run folders left as .partial: $partial"
"$formloop" run "$work/parts4" --kb "$kb" --jobs 2 --no-report --force --out "$work/rerun" >/dev/null 2>"$work/rerun.log" && rc=0 || rc=$?
python3 - "$work/rerun" "$rc" <<'PY'
import json, sys
b = json.load(open(sys.argv[1] + "/batch_summary.json"))
print("rerun: exit %s; %d within / %d out of tolerance / %d failed of %d" % (sys.argv[2], b["within_tolerance"],
      b["out_of_tolerance"], b["failed"], b["count"]))
PY
echo "rerun: cases now $(count "$kb")"

fi

# ---- 16 parts, --jobs 1 vs --jobs 2 (SQLite library)
if want batch; then
for jobs in 1 2; do
  "$formloop" kb init "$work/batch-j$jobs.db" --starter >/dev/null 2>&1
  start=$(date +%s.%N)
  "$formloop" run "$work/parts16" --kb "$work/batch-j$jobs.db" --jobs $jobs --no-report --out "$work/batch-j$jobs" >/dev/null 2>"$work/batch-j$jobs.log" || true
  end=$(date +%s.%N)
  echo "batch: 16 parts --jobs $jobs (SQLite library): $(python3 -c "print(round($end - $start, 1))") s, failed $(python3 -c "import json; print(json.load(open('$work/batch-j$jobs/batch_summary.json'))['failed'])")"
done
fi
