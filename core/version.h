#pragma once
// formloop's version: the one string, CMake's project(VERSION) (root CMakeLists.txt), given to
// core/version.cc alone at build time. `formloop --version`, summary.json's formloop_version and the
// programs' title comments all print it.

namespace formloop {

const char* Version();  // e.g. "0.2.0"

}  // namespace formloop
