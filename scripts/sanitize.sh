#!/usr/bin/env bash
# Builds formloop and its test suite under AddressSanitizer + UndefinedBehaviorSanitizer (clang, the build folder
# of scripts/sanitizer_build.sh, shared with scripts/fuzz.sh) and runs ctest there. Any sanitizer report fails
# the test that triggered it (UBSan does not recover; ASan and LeakSanitizer abort). Third-party findings are
# suppressed in scripts/ubsan.supp and scripts/lsan.supp, each with its reason; none of formloop's own.
#
#   scripts/sanitize.sh [CTEST ARGS ...]      e.g. scripts/sanitize.sh -R '^metrology\.'
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/sanitizer_build.sh"

san_configure
cmake --build "$SAN_BUILD" --parallel "$SAN_JOBS"
# Sanitized code runs several times slower: ctest's per-test timeout is raised accordingly.
cd "$SAN_BUILD"
ctest --parallel "$SAN_JOBS" --timeout 1500 --output-on-failure "$@"
