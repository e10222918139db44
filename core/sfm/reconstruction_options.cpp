#include "core/sfm/reconstruction_options.h"

namespace uavm::sfm {

bool ReconstructionOptions::Check(std::string* why) const {
  auto fail = [&](const char* m) {
    *why = m;
    return false;
  };
  if (threads < 1) return fail("--threads must be >= 1");
  if (!(feature_scale >= 0.0 && feature_scale <= 1.0)) return fail("feature_scale must be in [0,1] (0 = automatic)");
  if (feature_scale == 0.0 && feature_long_side_px < 100) return fail("feature_long_side_px must be >= 100");
  if (max_features < 100) return fail("max_features must be >= 100");
  if (!(ratio > 0.0 && ratio < 1.0)) return fail("ratio must be in (0,1)");
  if (!(fundamental_threshold_px > 0.0)) return fail("fundamental_threshold_px must be > 0");
  if (round_reprojection_px.empty()) return fail("round_reprojection_px needs at least one round");
  if (!(dense_image_scale > 0.0 && dense_image_scale <= 1.0)) return fail("dense_image_scale must be in (0,1]");
  if (dense_sample_step < 1 || fusion_min_pairs < 1) return fail("dense_sample_step, fusion_min_pairs >= 1");
  if (dsm_fill_cells < 0) return fail("--dsm-fill must be >= 0");
  if (!checkpoints.empty() && gcp_file.empty()) return fail("--checkpoints needs --gcp");
  if (!gcp_file.empty() && !control.Check(why)) return false;
  return true;
}

}  // namespace uavm::sfm
