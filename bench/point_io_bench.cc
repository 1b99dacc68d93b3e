// Reading and writing one 100,000-point set (normals + 2 scalar columns) with formloop's binary PLY,
// ASCII CSV and PCD (binary, through PCL's header), next to PCL's own loader as the reference:
// pcl::io::loadPCDFile into pcl::PointCloud<pcl::PointNormal> of a float PCD written by PCL (it holds
// x y z normal_* curvature, so it carries 4 bytes per value instead of 8 and one scalar instead of two).
//
//   ./build/bench/formloop_bench_point_io --benchmark_min_time=0.2

#include <benchmark/benchmark.h>
#include <pcl/io/pcd_io.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "core/point_io.h"
#include "core/random.h"

namespace formloop {
namespace {

namespace fs = std::filesystem;
constexpr std::size_t kPoints = 100'000;

const PointSet& Sample() {
  static const PointSet sample = [] {
    Rng rng(20240601);
    PointSet set;
    std::vector<double> deviation_um(kPoints);
    std::vector<double> intensity(kPoints);
    for (std::size_t i = 0; i < kPoints; ++i) {
      set.points.emplace_back(rng.Uniform(-500, 500), rng.Uniform(-500, 500), rng.Uniform(-50, 50));
      set.normals.push_back(Eigen::Vector3d(rng.Normal(), rng.Normal(), rng.Normal() + 3).normalized());
      deviation_um[i] = rng.Normal(0, 3);
      intensity[i] = rng.Uniform();
    }
    set.SetScalar("deviation_um", std::move(deviation_um));
    set.SetScalar("intensity", std::move(intensity));
    return set;
  }();
  return sample;
}

const fs::path& Folder() {
  static const fs::path folder = [] {
    fs::path path = fs::temp_directory_path() / ("formloop_bench_point_io_" + std::to_string(::getpid()));
    fs::create_directories(path);
    return path;
  }();
  return folder;
}

void Count(benchmark::State& state, const fs::path& file) {
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * kPoints));
  state.SetBytesProcessed(static_cast<std::int64_t>(state.iterations() * fs::file_size(file)));
}

void Write(benchmark::State& state, const char* name, bool binary) {
  const fs::path file = Folder() / name;
  for (auto _ : state) {
    const Status status = WritePoints(file, Sample(), {.binary = binary});
    if (!status.ok()) state.SkipWithError(status.ToString().c_str());
  }
  Count(state, file);
}

void Read(benchmark::State& state, const char* name, bool binary) {
  const fs::path file = Folder() / name;
  if (!WritePoints(file, Sample(), {.binary = binary}).ok()) state.SkipWithError("cannot write the input");
  for (auto _ : state) {
    auto points = ReadPoints(file);
    if (!points.ok()) state.SkipWithError(points.status().ToString().c_str());
    benchmark::DoNotOptimize(points);
  }
  Count(state, file);
}

void BM_WritePlyBinary(benchmark::State& state) { Write(state, "w.ply", true); }
void BM_ReadPlyBinary(benchmark::State& state) { Read(state, "r.ply", true); }
void BM_WriteCsv(benchmark::State& state) { Write(state, "w.csv", false); }
void BM_ReadCsv(benchmark::State& state) { Read(state, "r.csv", false); }
void BM_WritePcdBinary(benchmark::State& state) { Write(state, "w.pcd", true); }
void BM_ReadPcdBinary(benchmark::State& state) { Read(state, "r.pcd", true); }

void BM_PclLoadPcdPointNormal(benchmark::State& state) {
  const fs::path file = Folder() / "pcl.pcd";
  pcl::PointCloud<pcl::PointNormal> cloud;
  const PointSet& sample = Sample();
  for (std::size_t i = 0; i < sample.size(); ++i) {
    pcl::PointNormal p;
    p.getVector3fMap() = sample.points[i].cast<float>();
    p.getNormalVector3fMap() = sample.normals[i].cast<float>();
    p.curvature = static_cast<float>(sample.scalars[0].values[i]);
    cloud.push_back(p);
  }
  if (pcl::io::savePCDFileBinary(file.string(), cloud) != 0) state.SkipWithError("cannot write the input");
  for (auto _ : state) {
    pcl::PointCloud<pcl::PointNormal> loaded;
    if (pcl::io::loadPCDFile(file.string(), loaded) != 0) state.SkipWithError("PCL cannot read the input");
    benchmark::DoNotOptimize(loaded);
  }
  Count(state, file);
}

BENCHMARK(BM_WritePlyBinary)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadPlyBinary)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_WriteCsv)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadCsv)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_WritePcdBinary)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadPcdBinary)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_PclLoadPcdPointNormal)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace formloop

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  std::error_code ignored;
  std::filesystem::remove_all(formloop::Folder(), ignored);
  return 0;
}
