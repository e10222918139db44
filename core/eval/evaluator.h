#pragma once
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "core/eval/ground_truth.h"
#include "core/session/session_dir.h"

namespace uavm::eval {

struct EvalOptions {
  int grid = 9;                // grid x grid points per frame
  int refine_iterations = 20;  // Levenberg-Marquardt steps after the DLT
  // The truth's camera (gt_camera.yaml): the frames are distorted pictures, so the true canvas point of frame pixel
  // p is canvas_from_frame(truth_camera.UndistortPixel(p)). A mosaicker that ignores the lens then shows the error it
  // really has. nullopt, or a camera without distortion: canvas_from_frame(p), as before the lens keys.
  std::optional<PinholeCamera> truth_camera;
  // The session's own camera, when its transforms act on undistorted pixels (a mosaicker that corrects the lens):
  // the mosaic point of p is mosaic_from_frame(session_camera.UndistortPixel(p)). nullopt: mosaic_from_frame(p).
  std::optional<PinholeCamera> session_camera;
};

struct FrameError {
  int index = -1;
  std::string filename;
  bool registered = false;
  double rms_px = 0.0;  // frame pixels, over the frame's grid; 0 when unregistered
  double max_px = 0.0;
  double path_length_px = 0.0;  // cumulative canvas-pixel distance flown by the true frame centres up to this frame
};

struct EvalResult {
  int frames = 0;
  int registered = 0;
  double registered_share = 0.0;
  double rms_px = 0.0;  // all grid points of all registered frames, frame pixels
  double max_px = 0.0;
  std::vector<FrameError> per_frame;  // one per ground-truth frame, in ground-truth order
  // Drift: per-frame RMS pooled over the first and last third of the registered frames (flight order), their ratio
  // (0 when the first third is error-free) and the least-squares slope of per-frame RMS against path length.
  double first_third_rms_px = 0.0;
  double last_third_rms_px = 0.0;
  double drift_ratio = 0.0;
  double drift_slope_px_per_kpx = 0.0;
  Mat3 canvas_from_mosaic = Mat3::Identity();  // the fitted global homography
};

// Compares a session's mosaic_from_frame with the true canvas_from_frame. Rows are paired by filename when every
// registered session filename appears in the ground truth, else by index. The mosaic's own frame is arbitrary, so
// one homography canvas_from_mosaic is fitted over all point pairs (normalised DLT + LM, weighted so the residual is
// in frame pixels); errors are then canvas-pixel distances divided by the true map's local scale sqrt|det J|. With a
// distorted truth_camera the grid is laid on the recorded frame and the local scale taken at each point's undistorted
// position: errors are in pixels of the ideal pinhole frame (uniform over it, the units of the homographies).
[[nodiscard]] bool EvaluateSession(const std::vector<TransformRow>& session, const std::vector<GtRow>& gt,
                                   cv::Size frame_size, EvalResult* result, std::string* error,
                                   const EvalOptions& options = {});

// The ground truth's per-frame closest affines as a session: evaluating it gives the error floor of an affine model.
[[nodiscard]] std::vector<TransformRow> AffineFloorSession(const std::vector<GtRow>& gt);

// JSON with rms_px, max_px, registered_share, affine_floor_* (when `affine_floor` is given), drift and per_frame.
[[nodiscard]] nlohmann::json ToJson(const EvalResult& result, const EvalResult* affine_floor);

// Fits tgt = H(src) (weighted least squares, h22 = 1); exposed for tests. Needs >= 4 points in general position.
[[nodiscard]] bool FitHomography(const std::vector<Vec2>& src, const std::vector<Vec2>& tgt,
                                 const std::vector<double>& weights, int iterations, Mat3* tgt_from_src);

}  // namespace uavm::eval
