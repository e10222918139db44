// uavmosaic-ground: thin entry point. `uavmosaic-ground stereo LEFT RIGHT --out DISP.tif` scores the dense matcher on
// one rectified pair; anything else is a reconstruction of a session directory (`SESSION_DIR --out DIR`).
#include <cstring>

#include "ground_app/reconstruct_command.h"
#include "ground_app/stereo_command.h"

int main(int argc, char** argv) {
  if (argc >= 2 && std::strcmp(argv[1], "stereo") == 0) {
    return uavm::ground::RunStereoCommand(argc - 1, argv + 1);
  }
  return uavm::ground::RunReconstructCommand(argc, argv);
}
