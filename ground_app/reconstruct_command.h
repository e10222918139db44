#pragma once

namespace uavm::ground {
// `SESSION_DIR --out DIR [options]`; argv[0] is the program name. Returns the process exit code (exit_codes.h).
int RunReconstructCommand(int argc, char** argv);
}  // namespace uavm::ground
