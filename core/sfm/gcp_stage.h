#pragma once
#include <Eigen/Core>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "core/sfm/control_points.h"
#include "core/sfm/frame_selection.h"
#include "core/sfm/gcp.h"
#include "core/sfm/initial_poses.h"
#include "core/sfm/session_import.h"

namespace uavm::sfm {

// The ground tool's GCP input, read and checked before any expensive stage: the list, its CRS (the products' CRS
// then), the local offset and the points tied to the reconstruction's images.
struct GcpInput {
  GcpList list;
  GcpCrs crs;
  Eigen::Vector2d offset = Eigen::Vector2d::Zero();  // products' x, y = local + offset, in the GCP CRS
  GcpBinding binding;
  // Horizontal control only: asked for (ControlOptions::horizontal_only), or every point's Z the same (all 0, or one
  // value for all: a file without heights), which LoadGcpInput says in the log and the report.
  bool horizontal_only = false;
};

// `used` are the reconstruction's frames in image-slot order. With GPS in the frames, GCPs far from the flight
// (more than max_distance_km beyond it) are refused: the CRS line or the axis order is then wrong.
[[nodiscard]] bool LoadGcpInput(const std::string& path, const std::vector<std::string>& checkpoints,
                                const Session& session, const std::vector<const SessionFrame*>& used,
                                double max_distance_km, GcpInput* out, nlohmann::json* js, std::string* error);

// The GCP file (none without options.gcp_file) read, checked and bound to the selected frames' image slots.
[[nodiscard]] bool BindGcpFile(const SelectedFrames& sel, const ReconstructionOptions& options,
                               std::unique_ptr<GcpInput>* gcp, nlohmann::json* js, std::string* error);

// 7b. The georeferenced model moved onto the GCPs and adjusted with them (checkpoints kept out), every point measured;
// the figures under (*js)["gcp"].
[[nodiscard]] bool AdjustToGcps(const std::vector<const SessionFrame*>& frames, const InitialModel& init, GcpInput* gcp,
                                const ReconstructionOptions& options, Reconstruction* rec, nlohmann::json* js,
                                std::string* error);

}  // namespace uavm::sfm
