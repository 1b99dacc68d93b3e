// `formloop kb ...`: the case-library maintenance tool. This first version creates and migrates.

#include <iostream>
#include <memory>

#include "app/command.h"
#include "core/log.h"
#include "kb/schema.h"

namespace formloop::app {

void AddKbCommand(CLI::App& root, CommandAction* action) {
  CLI::App* kb = root.add_subcommand("kb", "Case-library maintenance (SQLite).");
  kb->require_subcommand(1);
  auto path = std::make_shared<std::string>();
  CLI::App* init = kb->add_subcommand(
      "init",
      "Create the case library at PATH (schema version in PRAGMA user_version, foreign keys on, WAL journal), or "
      "migrate an existing library to the current schema. Prints a JSON report on stdout.");
  init->add_option("path", *path, "case library file, e.g. cases.db")->required();
  init->callback([path, action] {
    *action = [path]() -> Status {
      FL_ASSIGN_OR_RETURN(kb::InitReport report, kb::InitLibrary(*path));
      log::Info("case library {} at schema version {} ({} migration(s) applied)", report.path,
                report.migration.to_version, report.migration.applied.size());
      std::cout << report.ToJson().dump(2) << std::endl;
      return Status::Ok();
    };
  });
}

}  // namespace formloop::app
