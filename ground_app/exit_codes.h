#pragma once

namespace uavm::ground {

// Documented exit codes of uavmosaic-ground (README's ground tool section lists them too).
enum ExitCode : int {
  kExitOk = 0,
  kExitStereoFailed = 1,          // `stereo`: an image unreadable, the options or the pair refused, no TIFF written
  kExitUsage = 2,                 // reconstruction: bad command line or options (`stereo`: CLI11's own codes)
  kExitOutputError = 4,           // the output directory cannot be created or written
  kExitReconstructionFailed = 5,  // the session cannot be read or reconstructed (too few frames, matches, points...)
};

}  // namespace uavm::ground
