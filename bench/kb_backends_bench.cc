// The case library on its two back ends side by side (issue 28): SQLite file vs PostgreSQL server.
//
//   formloop_bench_kb_backends POSTGRES_URL [cases] [adds] [lookups]
//
// (defaults 100000 2000 1000). POSTGRES_URL names an empty database or schema (e.g. one from
// tests/kb/postgres_server.sh with ?options=-csearch_path%3Dbench after `CREATE SCHEMA bench`). Per
// back end: a library of `cases` synthetic cases is built by one import (the way a plant moves a
// library over), then
//   - `kb add` throughput: `adds` more cases, one Library::AddCase (one transaction, audit row,
//     change counter) each, as `formloop kb add` and the retain step write them;
//   - lookup latency p50/p99: GetCase of `lookups` random uids (one indexed read + its concepts);
//   - the full read retrieval starts from: ListCases() of the whole library (3 repetitions, median);
// printed as one table. Run the Release build, nice'd, on an otherwise quiet machine if possible.
// Durability differs unless the server is set up like the SQLite file: tests/kb/postgres_server.sh
// runs its throw-away server with fsync=off and synchronous_commit=off, which favours PostgreSQL's
// commit rate; a production server (fsync on) pays a WAL flush per commit as SQLite does.

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "kb/library.h"
#include "kb/schema.h"

namespace {

using formloop::kb::CaseRecord;
using formloop::kb::Library;
using Clock = std::chrono::steady_clock;

double Ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

CaseRecord Synthetic(int index, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  static const char* kFamilies[] = {"freeform", "turbine_blade", "mould_cavity"};
  static const char* kMaterials[] = {"H13", "Ti-6Al-4V", "Al 6061"};
  CaseRecord r;
  char uid[32];
  std::snprintf(uid, sizeof uid, "bench-%07d", index);
  r.uid = uid;
  r.name = "bench part " + std::to_string(index);
  r.family = kFamilies[index % 3];
  r.part = {
      {"tolerance_mm", 0.01 + 0.05 * unit(rng)}, {"batch_size", 1 + index % 20}, {"material", kMaterials[index % 3]}};
  r.simulation = {
      {"effect_models",
       {{{"machine", "dmu50"},
         {"effects", {{{"name", "tool_deflection"}, {"estimate", 0.003 * unit(rng)}, {"standard_error", 4e-4}}}}}}}};
  r.manufacturing = {{"machine", "dmu50"},
                     {"tools", {{{"type", "ball_end"}, {"radius_mm", 3.0}}}},
                     {"compensation", {{"loops", {{{"form_error_mm", 0.05 * unit(rng)}}}}}}};
  std::vector<double> d;
  for (int k = 0; k < 24; ++k) d.push_back(unit(rng) * 10.0 - 5.0);
  r.descriptor = d;
  r.concepts = {{"shape", r.family}, {"material", kMaterials[index % 3]}};
  r.created_at = r.updated_at = "2026-11-26T00:00:00.000Z";
  return r;
}

struct Row {
  std::string backend;
  double build_s = 0, adds_per_s = 0, p50_ms = 0, p99_ms = 0, list_s = 0;
  long long cases = 0;
};

double Percentile(std::vector<double> v, double p) {
  std::sort(v.begin(), v.end());
  return v[static_cast<std::size_t>(p * static_cast<double>(v.size() - 1))];
}

bool Measure(const std::string& name, const std::string& library, int cases, int adds, int lookups, Row* row) {
  row->backend = name;
  auto init = formloop::kb::InitLibrary(library);
  if (!init.ok()) {
    std::fprintf(stderr, "%s\n", init.status().ToString().c_str());
    return false;
  }
  auto opened = Library::Open(library);
  if (!opened.ok()) {
    std::fprintf(stderr, "%s\n", opened.status().ToString().c_str());
    return false;
  }
  Library& lib = **opened;
  std::mt19937_64 rng(2811);
  std::string text = nlohmann::json{{"format", formloop::kb::kExportFormatName},
                                    {"format_version", formloop::kb::kExportFormatVersion},
                                    {"schema_version", formloop::kb::LatestSchemaVersion()},
                                    {"cases", cases}}
                         .dump() +
                     "\n";
  for (int i = 0; i < cases; ++i)
    text += nlohmann::json{{"type", "case"}, {"case", Synthetic(i, rng).ToJson()}}.dump() + "\n";
  auto t0 = Clock::now();
  auto imported = lib.ImportText(text, "bench");
  if (!imported.ok()) {
    std::fprintf(stderr, "%s\n", imported.status().ToString().c_str());
    return false;
  }
  row->build_s = Ms(Clock::now() - t0) / 1000;
  t0 = Clock::now();
  for (int i = 0; i < adds; ++i) {
    const formloop::Status s = lib.AddCase(Synthetic(cases + i, rng));
    if (!s.ok()) {
      std::fprintf(stderr, "%s\n", s.ToString().c_str());
      return false;
    }
  }
  row->adds_per_s = adds / (Ms(Clock::now() - t0) / 1000);
  std::vector<double> latency;
  std::uniform_int_distribution<int> pick(0, cases + adds - 1);
  for (int i = 0; i < lookups; ++i) {
    char uid[32];
    std::snprintf(uid, sizeof uid, "bench-%07d", pick(rng));
    const auto t = Clock::now();
    auto got = lib.GetCase(uid);
    latency.push_back(Ms(Clock::now() - t));
    if (!got.ok()) {
      std::fprintf(stderr, "%s\n", got.status().ToString().c_str());
      return false;
    }
  }
  row->p50_ms = Percentile(latency, 0.5);
  row->p99_ms = Percentile(latency, 0.99);
  std::vector<double> lists;
  for (int rep = 0; rep < 3; ++rep) {
    const auto t = Clock::now();
    auto all = lib.ListCases();
    lists.push_back(Ms(Clock::now() - t) / 1000);
    if (!all.ok()) return false;
    row->cases = static_cast<long long>(all->size());
  }
  row->list_s = Percentile(lists, 0.5);
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: formloop_bench_kb_backends POSTGRES_URL [cases] [adds] [lookups]\n");
    return 2;
  }
  const std::string pg = argv[1];
  const int cases = argc > 2 ? std::atoi(argv[2]) : 100000;
  const int adds = argc > 3 ? std::atoi(argv[3]) : 2000;
  const int lookups = argc > 4 ? std::atoi(argv[4]) : 1000;
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("formloop-kb-bench-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::vector<Row> rows(2);
  const bool ok = Measure("SQLite (file, WAL)", (dir / "bench.db").string(), cases, adds, lookups, &rows[0]) &&
                  Measure("PostgreSQL 15 (loopback TCP)", pg, cases, adds, lookups, &rows[1]);
  std::filesystem::remove_all(dir);
  if (!ok) return 1;
  std::printf("case library back ends: %d cases built by one import, %d `kb add`s, %d lookups\n", cases, adds, lookups);
  std::printf("%-30s %10s %12s %12s %12s %14s %9s\n", "back end", "import s", "adds/s", "get p50 ms", "get p99 ms",
              "list all s", "cases");
  for (const Row& r : rows) {
    std::printf("%-30s %10.2f %12.1f %12.3f %12.3f %14.2f %9lld\n", r.backend.c_str(), r.build_s, r.adds_per_s,
                r.p50_ms, r.p99_ms, r.list_s, r.cases);
  }
  return 0;
}
