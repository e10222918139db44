#pragma once
#include <string>

#include "core/sfm/reconstruction.h"

namespace uavm::sfm {

// COLMAP 3.8 text model: cameras.txt (one camera, OPENCV, or FULL_OPENCV when k3 != 0), images.txt (qw qx qy qz =
// world-to-camera rotation, t = -R c, then the 2-D points with their POINT3D_ID or -1), points3D.txt (tracks).
// COLMAP's pixel convention puts the centre of the top-left pixel at (0.5, 0.5); ours at (0, 0): 0.5 is added to
// the principal point and every 2-D point on export and removed on import.
[[nodiscard]] bool WriteColmapText(const Reconstruction& rec, const std::string& dir, std::string* error);
[[nodiscard]] bool ReadColmapText(const std::string& dir, Reconstruction* rec, std::string* error);

}  // namespace uavm::sfm
