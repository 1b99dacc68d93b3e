#pragma once
// Machine profiles for the virtual machine (issue 8): what a simulated machine/tool/material really does,
// as data. The pipeline hands a profile to the virtual machine and never reads it otherwise; everything it
// learns about the machine comes through the probe measurements.
//
//   {"format": "formloop-machine-profile", "version": 1,
//    "name": "vm-mill-a",                      the machine's name (the key of learned models in the library)
//    "description": "...",
//    "model": {formloop-model},                the true effects (simulation/model.h), noise included
//    "probe": {"ball_radius_mm": 1.0, "pretravel_mm": 0.0}}   optional: the probe the machine really has
//
// `formloop run --machine virtual:NAME` reads data/machines/NAME.json (or a path ending in .json).

#include <filesystem>
#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/probe.h"
#include "simulation/model.h"

namespace formloop::app {

inline constexpr const char* kMachineProfileFormat = "formloop-machine-profile";
inline constexpr int kMachineProfileVersion = 1;

struct MachineProfile {
  std::string name;
  std::string description;
  sim::Model model;
  std::optional<metrology::ProbeModel> probe;
  nlohmann::json ToJson() const;
  static Result<MachineProfile> FromJson(const nlohmann::json& json, const std::string& source);
};

// NAME (data/machines/NAME.json under `data_dir`) or a path to a .json file.
Result<MachineProfile> ReadMachineProfile(const std::string& name_or_path, const std::filesystem::path& data_dir);

}  // namespace formloop::app
