#include "app/surface_source.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <system_error>

#include <Geom_BSplineSurface.hxx>
#include <Standard_Failure.hxx>

#include "core/atomic_file.h"
#include "core/file_hash.h"
#include "core/point_io.h"
#include "reconstruction/cad_io.h"
#include "reconstruction/cad_region.h"
#include "reconstruction/scattered_fit.h"
#include "reconstruction/trim.h"

namespace formloop::app {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr NumberRange kPositive{.min = 0, .exclusive_min = true};

// An error from a lower layer, reported against the part file's surface field.
Status InSurface(const std::string& part_source, const std::string& field, const Status& status) {
  return Status(status.code() == StatusCode::kNotFound ? StatusCode::kBadInput : status.code(),
                part_source + ": field 'surface." + field + "': " + status.message());
}

// "faces" / "face_names" through JsonFields, plus the rule they share: when given, not empty.
template <typename T>
Status NonEmpty(const JsonFields& f, const std::string& key, const std::vector<T>& read, const std::string& example) {
  if (!f.Has(key) || !read.empty()) return Status::Ok();
  return Status::BadInput(Where{.file = f.source(), .field = f.Path(key)}, "is an empty array",
                          "write e.g. " + example +
                              " (as `formloop fit FILE --list-faces` lists them), or leave it "
                              "out for a file with one face");
}

recon::CadRegionSelector RegionOf(const SurfaceFile& file) {
  return recon::CadRegionSelector{.indices = file.faces, .names = file.face_names};
}

bool SingleFace(const SurfaceFile& file) { return file.faces.size() <= 1 && file.face_names.size() <= 1; }

recon::CadFaceSelector FaceOf(const SurfaceFile& file) {
  recon::CadFaceSelector selector;
  if (!file.faces.empty()) selector.index = file.faces.front();
  if (!file.face_names.empty()) selector.name = file.face_names.front();
  selector.reverse = file.reverse;
  return selector;
}

// A scan is fitted with the thin-plate energy, λ by GCV, on the net the GCV ladder chooses (not the fit's
// least-squares default): Q is machined up to the points' parameter box, and least squares extrapolates a
// corner the points miss with no energy to hold it. Measured with 10,000 points and 5 µm noise
// (ScatteredFitNoiseDefault against ScatteredFitNoise): beyond the samples' hull egg_box 159 -> 35 µm,
// cylinder 14.8 -> 7.7 µm, the others within 1 µm of each other; truth RMS lower on every reference surface;
// the fit takes about twice as long (10,000 points: 0.09 -> 0.18 s CPU).
recon::ScatteredFitOptions ScanOptions(const SurfaceFile& file) {
  recon::ScatteredFitOptions o;
  o.smoothing = recon::ScatteredFitOptions::Smoothing::kGcv;
  o.adaptive = file.method == "adaptive";
  o.u_poles = file.u_poles;
  o.v_poles = file.v_poles;
  o.tolerance_mm = file.fit_tolerance_mm;
  return o;
}

// Q restricted (exactly) to the points' parameter box: the scattered fit's domain reaches beyond the data.
Result<recon::BSplineSurface> RestrictToDataBox(const recon::BSplineSurface& q, const json& details) {
  if (!details.contains("data_box") || !details["data_box"].is_array() || details["data_box"].size() != 4) return q;
  const double u0 = details["data_box"][0], u1 = details["data_box"][1], v0 = details["data_box"][2],
               v1 = details["data_box"][3];
  const recon::ParamDomain d = q.domain();
  if (!(u1 > u0 && v1 > v0)) return q;
  try {
    Handle(Geom_BSplineSurface) copy = Handle(Geom_BSplineSurface)::DownCast(q.geom()->Copy());
    copy->Segment(std::max(u0, d.u_min), std::min(u1, d.u_max), std::max(v0, d.v_min), std::min(v1, d.v_max));
    return recon::BSplineSurface(copy);
  } catch (const Standard_Failure&) {
    return Status::Internal("restricting the scan's Q to the points' parameter box failed");
  }
}

}  // namespace

std::string SurfaceFile::CopyName() const { return fs::path(name).filename().string(); }

json SurfaceFile::ToJson(const std::string& file_name) const {
  json out;
  if (kind == Kind::kCad) {
    out = {{"cad", file_name}, {"sha256", sha256}};
    if (!faces.empty()) out["faces"] = faces;
    if (!face_names.empty()) out["face_names"] = face_names;
    if (reverse) out["reverse"] = true;
    if (!SingleFace(*this)) {
      out["sample_spacing_mm"] = sample_spacing_mm;
      out["max_deviation_fraction"] = max_deviation_fraction;
    }
  } else {
    out = {{"points", file_name}, {"sha256", sha256}, {"method", method}};
    if (u_poles > 0) out["poles"] = {u_poles, v_poles};
    if (method == "adaptive") out["tolerance_mm"] = fit_tolerance_mm;
  }
  return out;
}

std::string SurfaceFile::Describe() const {
  if (kind == Kind::kPoints) return "scan:" + CopyName();
  std::string text = "cad:" + CopyName();
  if (!faces.empty() || !face_names.empty()) {
    text += "[";
    for (std::size_t k = 0; k < faces.size(); ++k) text += (k ? "," : "") + std::to_string(faces[k]);
    for (std::size_t k = 0; k < face_names.size(); ++k) text += (k ? "," : "") + face_names[k];
    text += "]";
  }
  return text;
}

bool IsSurfaceFile(const json& surface) {
  return surface.is_object() && (surface.contains("cad") || surface.contains("points"));
}

Result<SurfaceFile> ParseSurfaceFile(const JsonFields& s, const std::string& part_source) {
  SurfaceFile f;
  const bool cad = s.Has("cad");
  if (cad && s.Has("points")) {
    return Status::BadInput(Where{.file = part_source, .field = "surface"}, "gives both \"cad\" and \"points\"",
                            "give one: the CAD model or the scan");
  }
  f.kind = cad ? SurfaceFile::Kind::kCad : SurfaceFile::Kind::kPoints;
  const std::string key = cad ? "cad" : "points";
  if (cad) {
    FL_RETURN_IF_ERROR(s.CheckKnown(
        {"cad", "faces", "face_names", "sha256", "sample_spacing_mm", "max_deviation_fraction", "reverse"}));
  } else {
    FL_RETURN_IF_ERROR(s.CheckKnown({"points", "sha256", "method", "poles", "tolerance_mm"}));
  }
  FL_RETURN_IF_ERROR(s.String(key, &f.name));
  if (f.name.empty()) {
    return Status::BadInput(Where{.file = part_source, .field = "surface." + key}, "is empty",
                            "give the file's path, relative to the part file");
  }
  const fs::path given(f.name);
  f.path = given.is_absolute() ? given : fs::path(part_source).parent_path() / given;
  std::error_code ec;
  if (!fs::is_regular_file(f.path, ec)) {
    return Status::BadInput(
        Where{.file = part_source, .field = "surface." + key},
        "file '" + f.name + "' does not exist (looked for " + f.path.string() + ")",
        "give the path of the " + std::string(cad ? "STEP or IGES file" : "point file") + " relative to the part file");
  }
  FL_ASSIGN_OR_RETURN(f.sha256, Sha256OfFile(f.path));
  std::string expected;
  FL_RETURN_IF_ERROR(s.OptionalString("sha256", &expected));
  if (!expected.empty() && expected != f.sha256) {
    return Status::BadInput(Where{.file = part_source, .field = "surface.sha256"},
                            "file '" + f.name + "' has SHA-256 " + f.sha256 + ", not the " + expected +
                                " this description was written with: the file changed",
                            "use the file the run was made with, or remove \"sha256\" to accept the new one");
  }
  if (cad) {
    if (s.Has("faces")) {
      std::vector<long long> faces;
      FL_RETURN_IF_ERROR(s.IntegerArray("faces", &faces, 0, std::numeric_limits<int>::max()));
      FL_RETURN_IF_ERROR(NonEmpty(s, "faces", faces, "[3, 4, 7] (0-based)"));
      f.faces.assign(faces.begin(), faces.end());
    }
    if (s.Has("face_names")) {
      FL_RETURN_IF_ERROR(s.StringArray("face_names", &f.face_names));
      FL_RETURN_IF_ERROR(NonEmpty(s, "face_names", f.face_names, "[\"top\"]"));
    }
    if (!f.faces.empty() && !f.face_names.empty()) {
      return Status::BadInput(Where{.file = part_source, .field = "surface.faces"},
                              "both \"faces\" and \"face_names\" are given", "choose the faces one way");
    }
    FL_RETURN_IF_ERROR(s.OptionalBool("reverse", &f.reverse));
    if (f.reverse && !SingleFace(f)) {
      return Status::BadInput(Where{.file = part_source, .field = "surface.reverse"},
                              "turns one face over; this surface is a region of several faces",
                              "give one face, or turn the faces over in the CAD system");
    }
    FL_RETURN_IF_ERROR(s.OptionalNumber("sample_spacing_mm", &f.sample_spacing_mm, kPositive));
    FL_RETURN_IF_ERROR(s.OptionalNumber("max_deviation_fraction", &f.max_deviation_fraction,
                                        {.min = 0, .max = 1, .exclusive_min = true}));
    // The faces are read now, so a missing face (the message lists the file's faces), an index out of range
    // or a unit-less IGES file is refused before the run starts.
    const Status read = SingleFace(f) ? recon::ReadCadFace(f.path, FaceOf(f)).status()
                                      : recon::ReadCadFaces(f.path, RegionOf(f)).status();
    if (!read.ok()) {
      return InSurface(part_source, !f.face_names.empty() ? "face_names" : !f.faces.empty() ? "faces" : "cad", read);
    }
  } else {
    FL_RETURN_IF_ERROR(s.OptionalString("method", &f.method));
    if (f.method != "scattered" && f.method != "adaptive") {
      return Status::BadInput(Where{.file = part_source, .field = "surface.method"},
                              "unknown fit method '" + f.method + "'", "use \"scattered\" or \"adaptive\"");
    }
    if (s.Has("poles")) {
      std::vector<long long> poles;
      FL_RETURN_IF_ERROR(s.IntegerArray("poles", &poles, 4, 1000));
      if (poles.size() != 2) {
        return Status::BadInput(Where{.file = part_source, .field = "surface.poles"},
                                "expected [nu, nv], got " + std::to_string(poles.size()) + " numbers",
                                "two integers from 4 to 1000, or leave it out for an automatic net");
      }
      f.u_poles = static_cast<int>(poles[0]);
      f.v_poles = static_cast<int>(poles[1]);
    }
    FL_RETURN_IF_ERROR(s.OptionalNumber("tolerance_mm", &f.fit_tolerance_mm, kPositive));
    // Read now: a file formloop cannot read, or too few points for the fit, is refused before the run.
    auto points = ReadPoints(f.path);
    if (!points.ok()) return InSurface(part_source, "points", points.status());
    const recon::ScatteredFitOptions o = ScanOptions(f);
    const std::size_t needed = f.u_poles > 0 ? static_cast<std::size_t>(f.u_poles) * static_cast<std::size_t>(f.v_poles)
                                             : static_cast<std::size_t>((o.degree + 1) * (o.degree + 1));
    if (points->points.size() < needed) {
      return Status::BadInput(Where{.file = part_source, .field = "surface.points"},
                              "'" + f.name + "' holds " + std::to_string(points->points.size()) +
                                  " points; the scattered fit of a degree-" + std::to_string(o.degree) +
                                  " surface needs at least " + std::to_string(needed) + " (one per control point)",
                              "use a denser scan (a scan normally holds thousands of points)");
    }
  }
  return f;
}

Result<SurfaceFromFile> BuildSurfaceFromFile(const SurfaceFile& file, double tolerance_mm) {
  SurfaceFromFile out;
  const std::string field = file.kind == SurfaceFile::Kind::kCad ? "cad" : "points";
  out.description = file.ToJson(file.name);
  if (file.kind == SurfaceFile::Kind::kCad && SingleFace(file)) {
    FL_ASSIGN_OR_RETURN(recon::CadFace face, recon::ReadCadFace(file.path, FaceOf(file)));
    out.q = face.surface;
    out.fit_check_max_mm = 0;
    out.report.method = "cad";
    out.report.residual = "none: Q is the face's own B-spline (converted exactly when it was another surface type)";
    out.description["face"] = {{"index", face.info.index},
                               {"name", face.info.name},
                               {"surface_type", face.info.surface_type},
                               {"converted", face.converted},
                               {"file_unit", face.file_unit}};
    out.description["trim"] = out.q.trim() != nullptr ? out.q.trim()->ToJson() : json(nullptr);
  } else if (file.kind == SurfaceFile::Kind::kCad) {
    FL_ASSIGN_OR_RETURN(std::vector<recon::CadFace> faces, recon::ReadCadFaces(file.path, RegionOf(file)));
    recon::RegionFitOptions o;
    o.sample_spacing_mm = file.sample_spacing_mm;
    o.max_cad_deviation_mm = file.max_deviation_fraction * tolerance_mm;
    auto fit = recon::FitCadRegion(faces, o);
    if (!fit.ok()) {
      return Status(fit.status().code(), "surface '" + file.Describe() + "': " + fit.status().message() +
                                             " (limit: surface.max_deviation_fraction " +
                                             FormatExact(file.max_deviation_fraction) + " of the form tolerance)");
    }
    out.q = fit->q;
    out.report = fit->report;
    out.fit_check_max_mm = fit->cad_deviation_max_mm;
    out.description["region"] = out.report.details["region"];
    out.description["deviation_limit_mm"] = o.max_cad_deviation_mm;
  } else {
    FL_ASSIGN_OR_RETURN(const PointSet points, ReadPoints(file.path));
    auto fit = recon::FitScattered(points.points, ScanOptions(file), &out.report);
    if (!fit.ok()) return Status(fit.status().code(), "surface.points '" + file.name + "': " + fit.status().message());
    FL_ASSIGN_OR_RETURN(out.q, RestrictToDataBox(*fit, out.report.details));
    out.description["restricted_to"] =
        "the points' parameter box (the fit's domain reaches beyond the data; that part is not machined)";
  }
  out.description["fit"] = out.report.ToJson();
  return out;
}

Status CopySurfaceFile(const SurfaceFile& file, const fs::path& dir) {
  FL_ASSIGN_OR_RETURN(const std::string hash, Sha256OfFile(file.path));
  if (hash != file.sha256) {
    return Status::BadInput("'" + file.path.string() + "' changed while the run was starting (SHA-256 " + hash +
                            ", parsed as " + file.sha256 + "). Fix: run again");
  }
  FL_ASSIGN_OR_RETURN(const std::string bytes, ReadFile(file.path));
  return WriteFileAtomic(dir / file.CopyName(), bytes, /*binary=*/true);
}

}  // namespace formloop::app
