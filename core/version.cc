#include "core/version.h"

#ifndef FORMLOOP_VERSION
#error "FORMLOOP_VERSION comes from the root CMakeLists.txt (project VERSION), set on this file in core/CMakeLists.txt"
#endif

namespace formloop {

const char* Version() { return FORMLOOP_VERSION; }

}  // namespace formloop
