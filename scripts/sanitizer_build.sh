# Sourced by scripts/fuzz.sh and scripts/sanitize.sh: configures (once) the clang build folder in which the
# libraries carry AddressSanitizer, UndefinedBehaviorSanitizer and libFuzzer's coverage instrumentation
# (-fsanitize=fuzzer-no-link: the fuzz targets link libFuzzer itself; the tests and formloop do not).
# The folder is separate from the Release build (default build-san; FORMLOOP_SAN_BUILD_DIR overrides).
# Needs the Debian packages clang-14, libclang-rt-14-dev (the sanitizer and libFuzzer runtimes) and llvm-14
# (llvm-symbolizer for readable reports); scripts/setup.sh deps installs them.

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
SAN_BUILD="${FORMLOOP_SAN_BUILD_DIR:-$ROOT/build-san}"
SAN_JOBS="${FORMLOOP_JOBS:-2}"

# Any report stops the process and fails the run: UBSan does not recover, ASan halts on the first error.
# LeakSanitizer stays on (libFuzzer checks every input for leaks; the tests at exit).
export ASAN_OPTIONS="${ASAN_OPTIONS:-abort_on_error=1:detect_stack_use_after_return=1:strict_string_checks=1:check_initialization_order=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1:suppressions=$ROOT/scripts/ubsan.supp}"
export LSAN_OPTIONS="${LSAN_OPTIONS:-suppressions=$ROOT/scripts/lsan.supp:print_suppressions=0}"
export ASAN_SYMBOLIZER_PATH="${ASAN_SYMBOLIZER_PATH:-$(command -v llvm-symbolizer-14 || true)}"

san_configure() {
  local missing=()
  for tool in clang-14 clang++-14; do command -v "$tool" >/dev/null || missing+=("$tool"); done
  if ((${#missing[@]})); then
    echo "missing ${missing[*]}: install the Debian packages clang-14 libclang-rt-14-dev llvm-14" \
         "(bash scripts/setup.sh deps)" >&2
    return 1
  fi
  local launcher=()
  command -v ccache >/dev/null && launcher=(-DCMAKE_C_COMPILER_LAUNCHER=ccache -DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
  local flags="-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer"
  [[ -f "$SAN_BUILD/build.ninja" ]] && return 0
  cmake -S "$ROOT" -B "$SAN_BUILD" -G Ninja "${launcher[@]}" \
    -DCMAKE_C_COMPILER=clang-14 -DCMAKE_CXX_COMPILER=clang++-14 \
    -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_C_FLAGS_RELWITHDEBINFO="-O1 -gline-tables-only" -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -gline-tables-only" \
    -DCMAKE_C_FLAGS="$flags" -DCMAKE_CXX_FLAGS="$flags" \
    -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=address,undefined" \
    -DFORMLOOP_FUZZ=ON -DFORMLOOP_BUILD_TESTS=ON -DFORMLOOP_BUILD_BENCH=OFF
}
