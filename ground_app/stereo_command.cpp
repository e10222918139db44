#include "ground_app/stereo_command.h"

#include <cstdio>

namespace uavm::ground {
int RunStereoCommand(int /*argc*/, char** /*argv*/) {
  std::fprintf(stderr, "uavmosaic-ground: stereo is not built yet\n");  // placeholder, replaced by the real command
  return 2;
}
}  // namespace uavm::ground
