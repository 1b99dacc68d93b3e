#pragma once
// What formloop may write over or delete, in one place (docs/ARCHITECTURE.md, "Outputs").
//
// formloop never writes an output onto one of the command's inputs, and deletes or replaces only folders it
// wrote itself:
//
//   - CheckOutputsNotInputs: every output path of a command against every input path (and the outputs
//     against each other). Two paths are the same file when they name the same inode (hard links,
//     symbolic links, "./a" and "a" alike) or, when one does not exist yet, the same canonical path. An
//     output folder that holds an input is refused too. The message names both paths and their options.
//
//   - OutputFolder: every folder formloop creates for its outputs (run folders and their .partial and
//     .failed forms, batch folders, diagnose, analyse and regress folders) carries the marker file
//     `.formloop-output`. A folder may be replaced or deleted only when it bears the marker, and never
//     when it is, or holds, the current directory or one of the command's inputs. A folder without the
//     marker is the user's: formloop refuses and says so, and deletes nothing.

#include <filesystem>
#include <string>
#include <vector>

#include "core/status.h"

namespace formloop {

// A path with the option (or argument) that named it, for messages: {"--out", "kb.jsonl"}.
struct NamedPath {
  std::string option;
  std::filesystem::path path;
};

// True when a and b are the same file or folder: same inode when both exist, else the same
// weakly-canonical path. Empty paths are never the same as anything.
bool SamePath(const std::filesystem::path& a, const std::filesystem::path& b);

// True when `inner` is `outer` or lies inside it (weakly-canonical paths, symbolic links resolved).
bool PathWithin(const std::filesystem::path& inner, const std::filesystem::path& outer);

// BadInput naming both paths when an output is an input (or holds one, for outputs that are folders:
// `output_folders` lists those), or when two outputs are the same file. Empty paths are skipped.
Status CheckOutputsNotInputs(const std::vector<NamedPath>& outputs, const std::vector<NamedPath>& inputs,
                             const std::vector<NamedPath>& output_folders = {});

class OutputFolder {
 public:
  static constexpr const char* kMarker = ".formloop-output";

  // True when `dir` is a folder holding the marker file.
  static bool HasMarker(const std::filesystem::path& dir);

  // Ok when `dir` does not exist, or is a folder that formloop wrote (marker) and that neither is nor
  // holds the current directory or one of `inputs`. `option` names the option in the message.
  static Status CheckReplaceable(const std::filesystem::path& dir, const std::string& option,
                                 const std::vector<NamedPath>& inputs);

  // CheckReplaceable, then deletes `dir` (nothing happens when it does not exist).
  static Status Remove(const std::filesystem::path& dir, const std::string& option,
                       const std::vector<NamedPath>& inputs);

  // Creates `dir` (and its parents) with the marker; `command` ("run", "diagnose", ...) goes into the
  // marker. An existing folder is adopted only when it is empty or already bears the marker; a folder
  // with other content is the user's and is refused (BadInput naming `option`).
  static Status Create(const std::filesystem::path& dir, const std::string& option, const std::string& command);

  // Moves `from` (a folder formloop wrote) onto `to`: `to` is removed first when it exists, under the rules
  // of CheckReplaceable; IoError names both when the rename fails.
  static Status Replace(const std::filesystem::path& from, const std::filesystem::path& to, const std::string& option,
                        const std::vector<NamedPath>& inputs);
};

// An output folder built whole or not at all: written in "<out>.partial" (with the marker), then renamed
// to <out> by Commit (replacing an older formloop folder there), or to "<out>.failed" by Fail (to keep a log
// and what was written). Destroyed without either, the staging folder is deleted.
class StagedOutputFolder {
 public:
  StagedOutputFolder() = default;
  StagedOutputFolder(const StagedOutputFolder&) = delete;
  StagedOutputFolder& operator=(const StagedOutputFolder&) = delete;
  ~StagedOutputFolder();

  // Refuses when `out` is or holds an input, when `out` exists and may not be replaced (`replace`
  // false, or OutputFolder::CheckReplaceable says no), or when "<out>.partial" / "<out>.failed" exist
  // and are not formloop's; then starts "<out>.partial" afresh (`had_partial` tells whether one was
  // left by an earlier, killed command).
  Status Open(const std::filesystem::path& out, const std::string& option, const std::string& command,
              const std::vector<NamedPath>& inputs, bool replace = true, bool* had_partial = nullptr);

  const std::filesystem::path& dir() const { return staging_; }  // where to write
  const std::filesystem::path& out() const { return out_; }
  const std::filesystem::path& failed() const { return failed_; }
  // Staging -> out (an older "<out>.failed" of formloop's is removed).
  Status Commit();
  // Staging -> "<out>.failed".
  Status Fail();

 private:
  std::filesystem::path out_, staging_, failed_;
  std::string option_;
  std::vector<NamedPath> inputs_;
  bool open_ = false;
};

}  // namespace formloop
