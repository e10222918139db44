#pragma once
#include <cstddef>
#include <functional>
#include <opencv2/core.hpp>
#include <string>

#include "core/radiometry/radiometry.h"
#include "core/sfm/reconstruction.h"

// The onboard program's radiometry of a flight, read back from its session for the ground tool's orthophoto: each
// frame's gains (radiometry.csv) and the shading every frame shares (report.json's "radiometry": the lens's falloff,
// the flat field, the sun's hotspot). The ground tool then divides out what the onboard map divided out, with the same
// core/radiometry model, instead of leaving the exposure steps between frames to the blend.
namespace uavm::sfm {

// *model as the onboard program solved it. False with *why when the session has none (radiometry off, refused, or a
// session written before it): the orthophoto is then made from the frames as they are.
[[nodiscard]] bool ReadSessionRadiometry(const std::string& session_dir, RadiometryModel* model, std::string* why);

// For the orthophoto (ortho_files.h's OrthoFrameCorrection): divides the session's radiometry out of the frame of
// `rec`'s image slot i (gains by its frame index, the hotspot turned by its onboard map's heading). Empty, with *why,
// when the session has none. `rec` must outlive it.
[[nodiscard]] std::function<void(size_t image, cv::Mat* bgr)> SessionRadiometryCorrection(
    const std::string& session_dir, const Reconstruction& rec, std::string* why);

}  // namespace uavm::sfm
