#!/usr/bin/env bash
# formloop set-up, build and run — the one entry point behind the README's quick start.
#
#   scripts/setup.sh demo    install what is missing, build (Release, all cores), run the demo job
#   scripts/setup.sh test    install what is missing, build, run the whole test suite (ctest)
#   scripts/setup.sh deps    only install what is missing
#   scripts/setup.sh build   install what is missing and build
#
# Every dependency is a Debian 12 package; nothing is downloaded at build or run time.
# Idempotent: when every package is present no apt command runs at all.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${FORMLOOP_BUILD_DIR:-$ROOT/build}"
JOBS="${FORMLOOP_JOBS:-$(nproc)}"

# Keep this list in step with docs/ARCHITECTURE.md ("Dependencies").
PACKAGES=(
  build-essential cmake ninja-build pkg-config
  libeigen3-dev libcgal-dev
  libocct-foundation-dev libocct-modeling-data-dev libocct-modeling-algorithms-dev libocct-data-exchange-dev
  libsqlite3-dev libpcl-dev
  libpqxx-dev       # the case library on PostgreSQL (kb/postgres_database.cc, libpqxx 6.4 over libpq)
  postgresql        # the tests start a real server of their own (tests/kb/postgres_server.sh: initdb, pg_ctl)
  libboost-dev      # Boost.Math's F distribution for diagnose's screening tests (PCL pulls it in too)
  libgtest-dev libgmock-dev libbenchmark-dev
  nlohmann-json3-dev libcli11-dev libfmt-dev libspdlog-dev
  libpng-dev        # PNG pictures embedded in each run's report.html
  libssl-dev        # SHA-256 (OpenSSL EVP) of the CAD and scan files a run copies into its folder
  libfuzzylite-dev  # the fuzzy feed controller's Mamdani inference (planning/fuzzy_feed.h)
  libnlopt-dev      # tests only: an independent optimum (COBYLA) for the cutting-parameter GA
  libnanoflann-dev  # header-only kd-tree in double: k-NN and distance-band spatial weights (metrology/spatial_weights.cc), far queries of the projector's start grid (reconstruction/point_grid.cc)
  libtbb-dev        # both cores with results identical to one (core/parallel.h: fixed chunks over TBB)
  chromium          # headless browser: the report tests render report.html (charts, 3-D view, width, errors)
  libjs-three       # three.js + OrbitControls, inlined into report.html for its 3-D view (no network)
  linuxcnc-uspace   # rs274 checks our LinuxCNC programs; the controller itself runs them (tests/linuxcnc)
  clang-14 libclang-rt-14-dev llvm-14  # scripts/fuzz.sh and sanitize.sh: libFuzzer, ASan/UBSan, llvm-symbolizer
)

log() { printf '[setup] %s\n' "$*" >&2; }

install_deps() {
  local missing=()
  for p in "${PACKAGES[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
      missing+=("$p")
    fi
  done
  if [ ${#missing[@]} -eq 0 ]; then
    log "all ${#PACKAGES[@]} packages present"
    return
  fi
  log "installing ${#missing[@]} missing package(s): ${missing[*]}"
  local SUDO=""
  if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null || { log "not root and no sudo: install as root: apt-get install ${missing[*]}"; exit 2; }
    SUDO="sudo"
  fi
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  log "packages installed"
}

build() {
  local gen=()
  command -v ninja >/dev/null && gen=(-G Ninja)
  # FORMLOOP_CMAKE_ARGS: extra configure options (CI passes -DFORMLOOP_WERROR=ON: our code builds warning-clean).
  local extra=()
  read -r -a extra <<<"${FORMLOOP_CMAKE_ARGS:-}"
  if [ ! -f "$BUILD_DIR/CMakeCache.txt" ]; then
    cmake -S "$ROOT" -B "$BUILD_DIR" "${gen[@]}" -DCMAKE_BUILD_TYPE=Release "${extra[@]}" >&2
  fi
  cmake --build "$BUILD_DIR" --parallel "$JOBS" >&2
}

cmd="${1:-demo}"
case "$cmd" in
  deps)  install_deps ;;
  build) install_deps; build ;;
  demo)
    install_deps; build
    out="${FORMLOOP_DEMO_OUT:-$ROOT/runs/demo}"
    kb="$out-kb.sqlite"   # a fresh starter case library each time, so the demo repeats exactly
    rm -f "$kb" "$kb-wal" "$kb-shm"
    mkdir -p "$(dirname "$out")"
    "$BUILD_DIR/app/formloop" --quiet kb init "$kb" --starter >/dev/null
    "$BUILD_DIR/app/formloop" run "$ROOT/data/parts/demo-saddle.json" --kb "$kb" --out "$out" --force >/dev/null
    log "demo finished: open $out/report.html (summary.json and every stage's report are in $out/)"
    ;;
  test)
    install_deps; build
    cd "$BUILD_DIR"
    ctest --output-on-failure --parallel "$JOBS" --timeout 900
    ;;
  *) echo "usage: scripts/setup.sh demo|test|deps|build" >&2; exit 2 ;;
esac
