#include "app/machine_profile.h"

#include "core/json_io.h"

namespace formloop::app {

nlohmann::json MachineProfile::ToJson() const {
  nlohmann::json j = {{"format", kMachineProfileFormat},
                      {"version", kMachineProfileVersion},
                      {"name", name},
                      {"description", description},
                      {"model", model.ToJson()}};
  if (probe) j["probe"] = {{"ball_radius_mm", probe->ball_radius_mm}, {"pretravel_mm", probe->pretravel_mm}};
  return j;
}

Result<MachineProfile> MachineProfile::FromJson(const nlohmann::json& json, const std::string& source) {
  if (!json.is_object()) return Status::BadInput(Where{.file = source}, "a machine profile must be a JSON object");
  JsonFields top(json, source);
  FL_RETURN_IF_ERROR(top.CheckKnown({"format", "version", "name", "description", "model", "probe", "comment"}));
  std::string format;
  FL_RETURN_IF_ERROR(top.String("format", &format));
  if (format != kMachineProfileFormat) {
    return Status::BadInput(Where{.file = source, .field = "format"}, "is '" + format + "'",
                            std::string("a machine profile has \"format\": \"") + kMachineProfileFormat + "\"");
  }
  long long version = 0;
  FL_RETURN_IF_ERROR(top.Integer("version", &version, 1));
  if (version > kMachineProfileVersion) {
    return Status::BadInput(Where{.file = source, .field = "version"},
                            "version " + std::to_string(version) + " is newer than this formloop reads (" +
                                std::to_string(kMachineProfileVersion) + ")",
                            "upgrade formloop");
  }
  MachineProfile profile;
  FL_RETURN_IF_ERROR(top.String("name", &profile.name));
  if (profile.name.empty()) return Status::BadInput(Where{.file = source, .field = "name"}, "must not be empty");
  FL_RETURN_IF_ERROR(top.OptionalString("description", &profile.description));
  if (!json.contains("model")) {
    return Status::BadInput(Where{.file = source, .field = "model"}, "required field is missing",
                            "give the machine's true effects as a formloop-model object");
  }
  auto model = sim::Model::FromJson(json["model"], source + " (model)");
  if (!model.ok()) return model.status();
  profile.model = std::move(model).value();
  std::optional<JsonFields> probe;
  FL_RETURN_IF_ERROR(top.Object("probe", &probe));
  if (probe) {
    FL_RETURN_IF_ERROR(probe->CheckKnown({"ball_radius_mm", "pretravel_mm"}));
    metrology::ProbeModel p;
    FL_RETURN_IF_ERROR(probe->OptionalNumber("ball_radius_mm", &p.ball_radius_mm, {.min = 0, .exclusive_min = true}));
    FL_RETURN_IF_ERROR(probe->OptionalNumber("pretravel_mm", &p.pretravel_mm));
    FL_RETURN_IF_ERROR(p.Validate());
    profile.probe = p;
  }
  return profile;
}

Result<MachineProfile> ReadMachineProfile(const std::string& name_or_path, const std::filesystem::path& data_dir) {
  std::filesystem::path path = name_or_path;
  if (path.extension() != ".json") path = data_dir / "machines" / (name_or_path + ".json");
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return Status::BadInput(
        Where{.file = path.string()}, "machine profile not found",
        "give a profile name from " + (data_dir / "machines").string() + " or a path to a .json file");
  }
  FL_ASSIGN_OR_RETURN(Json json, ReadJsonFile(path));
  return MachineProfile::FromJson(json, path.string());
}

}  // namespace formloop::app
