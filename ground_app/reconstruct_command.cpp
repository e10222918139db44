#include "ground_app/reconstruct_command.h"

#include <cstdio>

namespace uavm::ground {
int RunReconstructCommand(int /*argc*/, char** /*argv*/) {
  std::fprintf(stderr, "uavmosaic-ground: reconstruct is not built yet\n");  // placeholder, replaced by the real command
  return 2;
}
}  // namespace uavm::ground
