#include "core/output_folder.h"

#include "core/atomic_file.h"

namespace formloop {
namespace fs = std::filesystem;
namespace {

fs::path Canonical(const fs::path& path) {
  std::error_code ec;
  fs::path absolute = fs::absolute(path, ec);
  if (ec) absolute = path;
  fs::path canonical = fs::weakly_canonical(absolute, ec);
  if (ec) return absolute.lexically_normal();
  // weakly_canonical keeps a trailing separator ("a/b/"); drop it so prefixes compare component-wise.
  if (!canonical.has_filename() && canonical.has_parent_path() && canonical != canonical.root_path()) {
    canonical = canonical.parent_path();
  }
  return canonical;
}

std::string Quote(const fs::path& path) { return "'" + path.string() + "'"; }

std::string Named(const NamedPath& p) { return p.option + " " + Quote(p.path); }

}  // namespace

bool SamePath(const fs::path& a, const fs::path& b) {
  if (a.empty() || b.empty()) return false;
  std::error_code ec;
  if (fs::exists(a, ec) && fs::exists(b, ec)) {
    const bool same = fs::equivalent(a, b, ec);
    if (!ec) return same;
  }
  return Canonical(a) == Canonical(b);
}

bool PathWithin(const fs::path& inner, const fs::path& outer) {
  if (inner.empty() || outer.empty()) return false;
  const fs::path in = Canonical(inner);
  const fs::path out = Canonical(outer);
  auto i = in.begin();
  for (auto o = out.begin(); o != out.end(); ++o, ++i) {
    if (i == in.end() || *i != *o) return false;
  }
  return true;
}

Status CheckOutputsNotInputs(const std::vector<NamedPath>& outputs, const std::vector<NamedPath>& inputs,
                             const std::vector<NamedPath>& output_folders) {
  auto refuse = [](const NamedPath& output, const std::string& what) {
    return Status::BadInput(Where{.file = output.path.string(), .field = output.option}, what,
                            "write the output to another path; formloop never writes an output onto an input");
  };
  for (const NamedPath& output : outputs) {
    for (const NamedPath& input : inputs) {
      if (SamePath(output.path, input.path)) {
        return refuse(output, "the output " + Named(output) + " is the input " + Named(input));
      }
    }
  }
  for (const NamedPath& folder : output_folders) {
    for (const NamedPath& input : inputs) {
      if (!input.path.empty() && !folder.path.empty() && PathWithin(input.path, folder.path)) {
        return refuse(folder, SamePath(folder.path, input.path)
                                  ? "the output folder " + Named(folder) + " is the input " + Named(input)
                                  : "the output folder " + Named(folder) + " holds the input " + Named(input));
      }
    }
  }
  std::vector<NamedPath> all = outputs;
  all.insert(all.end(), output_folders.begin(), output_folders.end());
  for (std::size_t i = 0; i < all.size(); ++i) {
    for (std::size_t j = i + 1; j < all.size(); ++j) {
      if (SamePath(all[i].path, all[j].path)) {
        return Status::BadInput(Where{.file = all[j].path.string(), .field = all[j].option},
                                "the outputs " + Named(all[i]) + " and " + Named(all[j]) + " are the same file",
                                "give each output its own path");
      }
    }
  }
  return Status::Ok();
}

bool OutputFolder::HasMarker(const fs::path& dir) {
  std::error_code ec;
  return fs::is_directory(dir, ec) && fs::is_regular_file(dir / kMarker, ec);
}

Status OutputFolder::CheckReplaceable(const fs::path& dir, const std::string& option,
                                      const std::vector<NamedPath>& inputs) {
  std::error_code ec;
  if (!fs::exists(fs::symlink_status(dir, ec))) return Status::Ok();
  const Where where{.file = dir.string(), .field = option};
  if (!fs::is_directory(dir, ec)) {
    return Status::BadInput(where, "exists and is not a folder; formloop replaces only folders it wrote",
                            "choose a new folder name");
  }
  const fs::path cwd = fs::current_path(ec);
  if (!ec && PathWithin(cwd, dir)) {
    return Status::BadInput(where,
                            "the folder is or holds the current directory " + Quote(cwd) +
                                "; formloop never replaces the folder you are working in",
                            "choose another output folder, or run formloop from outside it");
  }
  for (const NamedPath& input : inputs) {
    if (!input.path.empty() && PathWithin(input.path, dir)) {
      return Status::BadInput(where, "the folder holds the input " + Named(input) + "; replacing it would delete it",
                              "choose another output folder, or move the input out of it");
    }
  }
  if (!HasMarker(dir)) {
    return Status::BadInput(where,
                            std::string("the folder exists and formloop did not write it (no ") + kMarker +
                                " marker file in it); formloop replaces or deletes only folders it wrote",
                            "choose a new output folder, or move or remove " + Quote(dir) + " yourself");
  }
  return Status::Ok();
}

Status OutputFolder::Remove(const fs::path& dir, const std::string& option, const std::vector<NamedPath>& inputs) {
  FL_RETURN_IF_ERROR(CheckReplaceable(dir, option, inputs));
  std::error_code ec;
  if (!fs::exists(fs::symlink_status(dir, ec))) return Status::Ok();
  fs::remove_all(dir, ec);
  if (ec) return Status::IoError("cannot remove the old output folder '" + dir.string() + "': " + ec.message());
  return Status::Ok();
}

Status OutputFolder::Create(const fs::path& dir, const std::string& option, const std::string& command) {
  std::error_code ec;
  if (fs::exists(dir, ec)) {
    if (!fs::is_directory(dir, ec)) {
      return Status::BadInput(Where{.file = dir.string(), .field = option}, "exists and is not a folder",
                              "choose a new folder name");
    }
    if (HasMarker(dir)) return Status::Ok();
    if (!fs::is_empty(dir, ec)) {
      return Status::BadInput(Where{.file = dir.string(), .field = option},
                              std::string("the folder exists, holds files and formloop did not write it (no ") +
                                  kMarker + " marker file in it); formloop writes only into folders it created",
                              "choose a new output folder");
    }
  }
  FL_RETURN_IF_ERROR(MakeDirectories(dir));
  return WriteFileAtomic(dir / kMarker, "{\"written_by\": \"formloop\", \"command\": \"" + command +
                                            "\", \"note\": \"formloop may replace or delete this folder\"}\n");
}

Status OutputFolder::Replace(const fs::path& from, const fs::path& to, const std::string& option,
                             const std::vector<NamedPath>& inputs) {
  FL_RETURN_IF_ERROR(Remove(to, option, inputs));
  std::error_code ec;
  fs::rename(from, to, ec);
  if (ec) return Status::IoError("cannot rename '" + from.string() + "' to '" + to.string() + "': " + ec.message());
  return Status::Ok();
}

StagedOutputFolder::~StagedOutputFolder() {
  if (!open_) return;
  std::error_code ec;
  fs::remove_all(staging_, ec);
}

Status StagedOutputFolder::Open(const fs::path& out, const std::string& option, const std::string& command,
                                const std::vector<NamedPath>& inputs, bool replace, bool* had_partial) {
  if (out.empty()) return Status::BadInput(Where{.field = option}, "no output folder given", "name the folder");
  out_ = out;
  staging_ = out;
  staging_ += ".partial";
  failed_ = out;
  failed_ += ".failed";
  option_ = option;
  inputs_ = inputs;
  FL_RETURN_IF_ERROR(CheckOutputsNotInputs({}, inputs, {{option, out}}));
  std::error_code ec;
  if (!replace && fs::exists(fs::symlink_status(out, ec))) {
    // Say what --force would do: replace a folder formloop made, nothing else (CheckReplaceable below).
    if (!fs::is_directory(fs::symlink_status(out, ec))) {
      return Status::BadInput(Where{.file = out.string(), .field = option},
                              "is a file, not a folder; the command writes a folder there",
                              "choose another folder name");
    }
    if (!OutputFolder::HasMarker(out)) {
      return Status::BadInput(Where{.file = out.string(), .field = option},
                              "the output folder already exists and formloop did not make it; formloop replaces "
                              "only folders it made, even with --force",
                              "choose another folder, or move or remove it yourself");
    }
    return Status::BadInput(Where{.file = out.string(), .field = option}, "the output folder already exists",
                            "choose another folder, or pass --force to replace it");
  }
  FL_RETURN_IF_ERROR(OutputFolder::CheckReplaceable(out, option, inputs));
  FL_RETURN_IF_ERROR(OutputFolder::CheckReplaceable(failed_, option, inputs));
  if (had_partial != nullptr) *had_partial = fs::exists(fs::symlink_status(staging_, ec));
  FL_RETURN_IF_ERROR(OutputFolder::Remove(staging_, option, inputs));
  FL_RETURN_IF_ERROR(OutputFolder::Create(staging_, option, command));
  open_ = true;
  return Status::Ok();
}

Status StagedOutputFolder::Commit() {
  if (!open_) return Status::Internal("StagedOutputFolder::Commit without Open");
  FL_RETURN_IF_ERROR(OutputFolder::Replace(staging_, out_, option_, inputs_));
  open_ = false;
  // An older failed attempt is obsolete now; a folder of the user's with that name stays.
  if (OutputFolder::HasMarker(failed_)) {
    std::error_code ec;
    fs::remove_all(failed_, ec);
  }
  return Status::Ok();
}

Status StagedOutputFolder::Fail() {
  if (!open_) return Status::Internal("StagedOutputFolder::Fail without Open");
  FL_RETURN_IF_ERROR(OutputFolder::Replace(staging_, failed_, option_, inputs_));
  open_ = false;
  return Status::Ok();
}

}  // namespace formloop
