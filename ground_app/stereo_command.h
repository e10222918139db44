#pragma once

namespace uavm::ground {
// `stereo LEFT RIGHT --out DISP.tif [--max-disparity N]`; argv[0] is "stereo". Returns the process exit code
// (exit_codes.h).
int RunStereoCommand(int argc, char** argv);
}  // namespace uavm::ground
