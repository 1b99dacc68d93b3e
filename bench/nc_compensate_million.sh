#!/bin/bash
# `formloop nc compensate` at the size of a finished part (issue 26; README "Performance"): 1,042,977 cutter
# locations and a 2,916-sample thin-plate field. Makes its inputs deterministically, then times the command.
#
#   bench/nc_compensate_million.sh [FORMLOOP [WORKDIR [RUNS]]]
#
# Inputs (WORKDIR, default /tmp/formloop_nc_compensate_million; made once, kept for the next call):
#   Q.step   the analytic reference surface "saddle" as formloop exports it (`surfaces export saddle`)
#   T.csv    its tool path: `nc path` with a 1.2 µm scallop and 0.048 mm longest step (483 passes, 1,042,977 CL)
#   P0.ngc   the nominal program `nc path` posts with it (LinuxCNC)
#   ds.csv   the field u,v,ds_um: a 54 × 54 grid over u in [-48, 48], v in [-38.4, 38.4] of
#            ds = 6 sin(2πu/60) cos(2πv/80) + 0.002 u v + 0.4 sin(0.9 u + 1.3 v) µm (6 decimals)
# Each run writes P1.ngc and S.bin and prints user + sys CPU, wall and peak RSS (GNU time), then checks the
# result with `nc check` (not timed). RUNS defaults to 3.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
formloop="$(readlink -f "${1:-$root/build/app/formloop}")"
work="${2:-/tmp/formloop_nc_compensate_million}"
runs="${3:-3}"
mkdir -p "$work"
cd "$work"

if [[ ! -s T.csv || ! -s P0.ngc || ! -s ds.csv ]]; then
  echo "making the inputs in $work" >&2
  "$formloop" surfaces export saddle --out Q.step > /dev/null
  "$formloop" nc path --surface Q.step --scallop-um 1.2 --max-spacing-mm 0.048 --toolpath T.csv --out P0.ngc \
    > /dev/null
  LC_ALL=C awk 'BEGIN {
    pi = 3.14159265358979323846; print "u,v,ds_um";
    for (i = 0; i < 54; ++i) for (j = 0; j < 54; ++j) {
      u = -48 + 96 * i / 53; v = -38.4 + 76.8 * j / 53;
      ds = 6 * sin(2 * pi * u / 60) * cos(2 * pi * v / 80) + 0.002 * u * v + 0.4 * sin(0.9 * u + 1.3 * v);
      printf "%.6f,%.6f,%.6f\n", u, v, ds } }' > ds.csv
fi
echo "inputs: $(($(wc -l < T.csv) - 4)) CL points, $(($(wc -l < ds.csv) - 1)) field samples" >&2

for ((r = 1; r <= runs; ++r)); do
  rm -f P1.ngc S.bin
  /usr/bin/time -f "%U %S %e %M" -o time.txt \
    "$formloop" nc compensate --toolpath T.csv --field ds.csv --nominal P0.ngc --out P1.ngc --side S.bin > /dev/null
  read -r user sys wall rss_kb < time.txt
  awk -v u="$user" -v s="$sys" -v w="$wall" -v m="$rss_kb" -v r="$r" \
    'BEGIN { printf "run %d: CPU %.2f s (user %.2f + sys %.2f), wall %.2f s, peak RSS %.3f GB\n", r, u + s, u, s, w, m / 1e6 }'
done
"$formloop" nc check --nominal P0.ngc --compensated P1.ngc --side S.bin --field ds.csv > check.json
echo "nc check: $(grep -o '"ok": *[a-z]*' check.json || echo 'see check.json')" >&2
sha256sum P1.ngc S.bin
