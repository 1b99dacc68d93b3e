#pragma once
// Mirror compensation of a tool path (spec/nc-gen.md §4): the compensated cutter-contact point is
// A = i − d_s(i)·n(i) (remove what was left, add back what was over-cut), then the cutter location
// as usual. Every moved CL point is recorded in a side file (nominal tip, applied offset vector,
// source) so a checker can recompute it from the two programs.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/atomic_file.h"
#include "core/status.h"
#include "nc-gen/post.h"
#include "nc-gen/toolpath.h"

namespace formloop::nc {

struct CompensationOptions {
  double max_offset_um = 200;  // safety: refuse any single offset larger than this
  Status Validate() const;
};

struct CompensationEntry {
  std::size_t cl_index = 0;
  long nominal_line = 0;      // line of the move in the nominal program (filled by caller)
  long compensated_line = 0;  // line in the compensated program (filled by caller)
  Eigen::Vector3d nominal_tip = Eigen::Vector3d::Zero();
  Eigen::Vector3d offset_mm = Eigen::Vector3d::Zero();  // compensated tip − nominal tip
  double systematic_um = 0;                             // d_s at the CC point
  // Where d_s was taken and along which normal (CompensateToolpath fills them), so a checker can
  // recompute −d_s·n from the field alone.
  int pass = 0;
  double u = 0, v = 0;
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  bool has_field_point = true;  // false for a lead (off Q) and for an old side file without u, v, nx..nz
  ClKind kind = ClKind::kCut;   // leads are never compensated (offset 0)
  // For a program formloop did not write (program_compensation.h): the fraction of the nominal block's
  // path at which this point lies (1 = its end; a split arc has one row per vertex).
  double lambda = 1;
};

struct Compensation {
  Toolpath path;                           // the compensated tool path
  std::vector<CompensationEntry> entries;  // one per CL point (CompensateToolpath; not WriteCompensatedProgram)
  std::size_t blocks = 0;                  // CL points = feed blocks = side-file rows
  double max_offset_um = 0;
  std::string source;  // e.g. "systematic field (Legendre degree 2) from loop 0"
  // Filled by WriteCompensatedProgram: the program's moves as read back from its text for the check (the
  // text itself is in the file, not held), and the check's largest disagreement between a side-file offset
  // and the offset recomputed from the two programs (µm; the program resolution limits it to about 0.1 µm).
  std::vector<ProgramMove> program_moves;
  double check_max_disagreement_um = 0;
  // The entries map the blocks of a program formloop did not write: the side file gets a lambda column
  // and `nc check` pairs rows with blocks by their lines (program_compensation.h).
  bool program_mapped = false;
};

// d_s(u, v) in mm at the CC point's parameters; loops pass the sum of every loop's field.
using SystematicField = std::function<double(double u, double v)>;

// CL points per parallel chunk of WriteCompensatedProgram's field evaluation (core/parallel.h): fixed, so the
// work is split the same way on any number of threads.
inline constexpr long kCompensationChunk = 1 << 14;

Result<Compensation> CompensateToolpath(const Toolpath& nominal, const SystematicField& systematic,
                                        const std::string& source, const CompensationOptions& options);

// Fills nominal_line / compensated_line: the i-th feed move of each program is CL point i.
Status AssignProgramLines(const std::vector<ProgramMove>& nominal, const std::vector<ProgramMove>& compensated,
                          Compensation* compensation);

// The side file, one row per CL point (= feed block) in cutting order, in one of two forms chosen by the
// path: a name ending in ".csv" gets CSV text, any other the compact binary form (`formloop run` writes
// loop-K/compensation_side.bin). ReadSideFile tells them apart by the first bytes and reads both (and the
// older CSV files without u, v, n or kind).
//
// CSV:
//   # formloop compensation side file: ...
//   # source: <Compensation::source>          (the offsets' source, for every row)
//   cl_index,pass,nominal_line,compensated_line,nominal_x,nominal_y,nominal_z,offset_x,offset_y,offset_z,ds_um,u,v,nx,ny,nz,kind
// nominal_* = nominal tip (mm, 6 decimals); offset_* = compensated − nominal tip (mm, 6 decimals);
// ds_um = d_s at the CC point (µm, 4 decimals); u, v = CC parameters (shortest exact text); nx..nz = unit
// normal at the CC point (9 decimals); kind = cut | lead-in | lead-out | off (leads and points of a foreign
// program where the tool does not touch Q keep their nominal place: offset 0, not checked against the
// field). The applied offset is −ds·n. A program formloop did not write adds a last column lambda (the
// point's fraction along its nominal block).
//
// Compact binary, version 1 (docs/formats.md; about a quarter of the CSV's size), little-endian:
//   8 bytes magic 0x89 "FLSIDE" '\n'; uint32 version = 1; uint32 flags (bit 0: a lambda per row); uint64 rows;
//   uint32 n + n bytes of UTF-8: the source; then per row, in cutting order (cl_index = the row's number):
//   uint8 kind (0 cut, 1 lead-in, 2 lead-out, 3 off); then pass, nominal_line, compensated_line, nominal
//   x, y, z (integer nm, 10^-6 mm), offset x, y, z (integer pm, 10^-9 mm), ds (integer 10^-6 µm), each a
//   zig-zag LEB128 varint of the change from the row before (from 0 for the first row); u, v as IEEE-754
//   doubles (exact); nx, ny, nz (integer 10^-9) as changes likewise; lambda as a double when flagged.
// Every stored quantity is at least as fine as the CSV's; the values read back are the decimals divided
// by their scale, as the CSV's text would give them.
struct SideState;  // compensation.cc: the last value of each delta-coded column
class SideFileWriter {
 public:
  // Opens the temporary file beside `path` (core/atomic_file.h); nothing is at `path` before Commit.
  SideFileWriter(const std::filesystem::path& path, const std::string& source, bool program_mapped);
  ~SideFileWriter();
  SideFileWriter(const SideFileWriter&) = delete;
  SideFileWriter& operator=(const SideFileWriter&) = delete;
  // The next row: entries must come in cutting order, cl_index 0, 1, 2, ...
  void Add(const CompensationEntry& entry);
  // Renames the file into place; the first failure otherwise (then nothing is written).
  Status Commit();

 private:
  void Flush();
  AtomicFile file_;
  bool binary_;
  bool program_mapped_;
  std::unique_ptr<SideState> state_;
  std::string buffer_;
  std::uint64_t rows_ = 0;
  Status status_;
};

Status WriteSideFile(const std::filesystem::path& path, const Compensation& compensation);

struct SideFile {
  std::string source;                      // from the "# source:" line ("" when absent)
  std::vector<CompensationEntry> entries;  // in file order
  bool has_field_points = false;           // the u, v, nx, ny, nz columns are present
  bool has_lambda = false;                 // the lambda column is present (a program formloop did not write)
};

// Reads what WriteSideFile writes (the u, v, nx, ny, nz and kind columns may be absent: older side files).
// BadInput names file, line and field for a missing column, a wrong field count or a bad number.
Result<SideFile> ReadSideFile(const std::filesystem::path& path);
// The same from text; `source` names it in messages.
Result<SideFile> ParseSideFile(const std::string& text, const std::string& source);

struct CheckOptions {
  int program_decimals = 4;  // coordinate decimals of the programs (PostOptions::decimals)
  double tolerance_um = 0;   // 0: derived from program_decimals (ProgramOffsetToleranceUm)
};

// Largest honest disagreement of an offset recomputed from two programs printed with `decimals`
// decimals: each axis of each tip is rounded by at most ½·10^−d mm, so the difference of two tips by
// 10^−d per axis, √3·10^−d mm in norm; plus 0.002 µm for the side file's 6-decimal rounding.
// decimals = 4 → 0.175 µm.
double ProgramOffsetToleranceUm(int decimals);

// One block (feed move = CL point) whose recomputed offset disagrees.
struct BlockCheck {
  std::size_t cl_index = 0;
  int pass = 0;
  long nominal_line = 0, compensated_line = 0;                  // lines in the two programs (as read from them)
  Eigen::Vector3d program_offset_mm = Eigen::Vector3d::Zero();  // compensated tip − nominal tip
  Eigen::Vector3d side_offset_mm = Eigen::Vector3d::Zero();     // offset_x..z of the side file
  Eigen::Vector3d field_offset_mm = Eigen::Vector3d::Zero();    // −d_s(u, v)·n from the field
  bool field_checked = false;
  double side_difference_um = 0, field_difference_um = 0, nominal_tip_difference_um = 0;
  std::vector<std::string> problems;  // one sentence per failed comparison
  std::string Describe() const;       // "block 17 (pass 2, nominal line 40, compensated line 40): ..."
};

struct CheckReport {
  std::size_t blocks = 0;
  bool field_checked = false;  // the field comparison ran (field given and side file has u, v, n)
  double tolerance_um = 0;
  double max_side_difference_um = 0, max_field_difference_um = 0;
  std::vector<BlockCheck> disagreeing;  // every block with at least one failed comparison, in order
  bool ok() const { return disagreeing.empty(); }
  nlohmann::json ToJson() const;
};

// One side-file row checked against the points the two programs give for it (mm): program offset
// against the side file's, the nominal point against the side file's, the lines (when the row names
// them), and −d_s(u, v)·n from `field` when report->field_checked and the row is on Q. A row with a
// problem is appended to report->disagreeing; the maxima are updated. CheckCompensation and
// CheckProgramCompensation (program_compensation.h) check every row through it.
void CheckRow(std::size_t index, const CompensationEntry& entry, const Eigen::Vector3d& nominal_tip, long nominal_line,
              const Eigen::Vector3d& compensated_tip, long compensated_line, const SystematicField& field,
              CheckReport* report);

// `formloop nc check`: for every feed block k (the k-th feed move of each program is side entry k),
// recomputes the offset b_k − a_k from the two programs and compares it (a) with the side file's
// offset, (b) with −d_s(u_k, v_k)·n_k from `field` (mm) when `field` is non-empty and the side file
// has u, v, n, and checks (c) the side file's nominal tip against the nominal program and (d) its line
// numbers (when non-zero) against the programs. Differences above the tolerance are reported per
// block with both values. Failed when the programs and side file disagree in their number of blocks.
Result<CheckReport> CheckCompensation(const std::vector<ProgramMove>& nominal,
                                      const std::vector<ProgramMove>& compensated, const SideFile& side,
                                      const SystematicField& field, const CheckOptions& options = {});

// The whole mirror step with nothing written unless everything passed: d_s once per CL point on Q (an
// offset above options.max_offset_um is refused with SafetyLimit), the compensated tips, the move list and
// the post of `dialect`, the compensated program read back, and then row by row the side-file entry checked
// against both programs and the field's value (CheckCompensation's test) and streamed into the side file's
// temporary file; the side file and then the program are renamed into place (should the program fail to
// write, the side file is removed). `nominal_moves` are the nominal program's moves as read from it (the
// same dialect; its i-th feed move is CL point i). `systematic` is called from several threads at once (each
// call a pure function of (u, v), as every field of formloop is; core/parallel.h). The result carries the program, its
// moves, the check's largest disagreement and the number of rows (`entries` and `path` stay empty: a million rows are
// not held). On any refusal or failed check neither file is written.
Result<Compensation> WriteCompensatedProgram(const Toolpath& nominal, const std::vector<ProgramMove>& nominal_moves,
                                             const SystematicField& systematic, const std::string& source,
                                             const CompensationOptions& options, const PostOptions& post,
                                             const std::filesystem::path& program_path,
                                             const std::filesystem::path& side_path,
                                             std::string_view dialect = "linuxcnc");

// Recomputes every offset from the two programs and compares with the side entries; returns the
// largest disagreement in µm (the program resolution limits it to about 0.1 µm).
Result<double> VerifyCompensation(const std::vector<ProgramMove>& nominal, const std::vector<ProgramMove>& compensated,
                                  const Compensation& compensation);

}  // namespace formloop::nc
