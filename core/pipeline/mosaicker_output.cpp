// Session outputs of the Mosaicker: transforms, graph, correspondences, mosaic and report.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string_view>
#include <unordered_set>

#include "core/mosaic/gdal_writer.h"
#include "core/pipeline/canvas_load.h"
#include "core/pipeline/mosaicker.h"
#include "core/util/clock.h"
#include "core/util/memory.h"

namespace uavm {

bool Mosaicker::WriteOutputs(const std::vector<int>& component, std::string* error) {
  resources_.EnterPhase("outputs");
  const std::unordered_set<int> in_component(component.begin(), component.end());
  std::vector<Mat3> canvas_from_original(frames_.size(), Mat3::Identity());
  cv::Size canvas(0, 0);
  const double scale =
      component.empty() ? options_.mosaic_scale : PlaceCanvas(component, &canvas_from_original, &canvas);
  // The map: the component placed by images, then what telemetry places where no image links.
  std::vector<int> placed = component;
  BridgeFrames(&placed, &canvas_from_original, &canvas);
  const std::unordered_set<int> in_map(placed.begin(), placed.end());
  if (!WriteTransformsCsv(in_map, canvas_from_original, error) || !WriteEdgeTables(in_component, error) ||
      !WriteFramesCsv(in_map, error) || !WriteCameraYaml(error) ||
      !WriteFileAtomic(paths_.Join("config.yaml"), ToYaml(options_), error))
    return false;
  CompositeResult composite;
  resources_.EnterPhase("compose");
  if (!placed.empty() && !CompositeMosaic(placed, canvas_from_original, canvas, scale, &composite, error)) return false;
  resources_.EnterPhase("products");
  nlohmann::json products = MakeProducts(placed, canvas_from_original, options_.write_tiff && !placed.empty());
  std::string err;
  if (options_.preview_every > 0 && !preview_.Write(paths_.Join("live.jpg"), &err))
    spdlog::warn("live preview: {}", err);
  FinishLiveTiles(nullptr);  // when no products were made (no-op after MakeProducts)
  return WriteReport(placed, composite, canvas, scale, std::move(products), error);
}

// Canvas: mosaic_scale canvas pixels per original pixel of the median frame (in the reference frame's orientation),
// shifted so the flight starts at (0,0). The median, not the reference frame: the first frame is often taken while
// the drone still climbs (caliterra's is 80 m lower than the last ones), and the canvas should follow the survey.
// Georeferenced, the canvas is turned north-up. Returns canvas pixels per reference-frame pixel.
double Mosaicker::PlaceCanvas(const std::vector<int>& component, std::vector<Mat3>* canvas_from_original,
                              cv::Size* canvas) {
  double scale = options_.mosaic_scale;
  const FrameState& ref = frames_[static_cast<size_t>(component.front())];
  std::vector<double> ref_px_per_px;
  for (int id : component) {
    const FrameState& f = frames_[static_cast<size_t>(id)];
    const Mat3 ref_from_original =
        ref.work_from_original.inverse() * engine_.mosaic_from_work(id) * f.work_from_original;
    ref_px_per_px.push_back(
        LocalScale(ref_from_original, Vec2(0.5 * (f.original_size.width - 1), 0.5 * (f.original_size.height - 1))));
  }
  std::nth_element(ref_px_per_px.begin(), ref_px_per_px.begin() + static_cast<long>(ref_px_per_px.size() / 2),
                   ref_px_per_px.end());
  const double median = ref_px_per_px[ref_px_per_px.size() / 2];
  if (median > 0 && std::isfinite(median)) scale /= median;
  // Placement on the canvas; `pre` (linear) turns the canvas, e.g. north-up once the flight is georeferenced.
  const auto place = [&](const Mat3& pre) {
    for (int attempt = 0; attempt < 2; ++attempt) {
      const Mat3 out_from_mosaic_work = pre * ResizeMap(scale, scale) * ref.work_from_original.inverse();
      for (int id : component)
        (*canvas_from_original)[static_cast<size_t>(id)] =
            out_from_mosaic_work * engine_.mosaic_from_work(id) * frames_[static_cast<size_t>(id)].work_from_original;
      const Bounds2 box = FootprintBounds(component, *canvas_from_original,
                                          [this](int id) { return frames_[static_cast<size_t>(id)].original_size; });
      const double w = std::ceil(box.maxx) - std::floor(box.minx) + 1;
      const double h = std::ceil(box.maxy) - std::floor(box.miny) + 1;
      if (std::max(w, h) > options_.max_canvas_side && attempt == 0) {
        const double shrink = options_.max_canvas_side / std::max(w, h);
        spdlog::warn("canvas {:.0f}x{:.0f} exceeds max_canvas_side {}; mosaic_scale {:.3f} -> {:.3f}", w, h,
                     options_.max_canvas_side, scale, scale * shrink);
        scale *= shrink * 0.999;
        continue;
      }
      const Mat3 shift = Translation(-std::floor(box.minx), -std::floor(box.miny));
      for (int id : component)
        (*canvas_from_original)[static_cast<size_t>(id)] = shift * (*canvas_from_original)[static_cast<size_t>(id)];
      *canvas = cv::Size(static_cast<int>(w), static_cast<int>(h));
      break;
    }
  };
  place(Mat3::Identity());
  georef_ = GeorefCanvas(component, canvas_from_original, place);
  return scale;
}

bool Mosaicker::WriteTransformsCsv(const std::unordered_set<int>& in_component,
                                   const std::vector<Mat3>& canvas_from_original, std::string* error) const {
  std::vector<TransformRow> rows;
  for (const auto& f : frames_) {
    TransformRow r;
    r.index = f.id;
    r.filename = f.name;
    r.registered = in_component.count(f.id) != 0;
    r.mosaic_from_frame = canvas_from_original[static_cast<size_t>(f.id)];
    if (r.registered) r.placed_by = placed_by_telemetry_.count(f.id) != 0 ? "telemetry" : "image";
    rows.push_back(r);
  }
  return WriteFileAtomic(paths_.Join("transforms.csv"), FormatTransformsCsv(rows), error);
}

// graph.csv and correspondences.csv (original-resolution pixels, so the ground tool needs no working sizes).
bool Mosaicker::WriteEdgeTables(const std::unordered_set<int>& in_component, std::string* error) {
  // correspondences.csv grows with the flight (~5 kB per edge): it is streamed to disk, edge by edge, and an edge
  // whose points are only in edges.bin is read, written and given back.
  std::ostringstream graph_csv;
  graph_csv << "src,tgt,src_file,tgt_file,matches,inliers,used\n";
  AtomicFileWriter corr_csv;
  if (!corr_csv.Open(paths_.Join("correspondences.csv"), error)) return false;
  corr_csv.Write("src,tgt,x_src,y_src,x_tgt,y_tgt\n");
  for (Edge& e : engine_.mutable_edges()) {
    const bool used = in_component.count(e.src) != 0 && in_component.count(e.tgt) != 0 && engine_.EdgeCounts(e);
    graph_csv << e.src << ',' << e.tgt << ',' << frames_[static_cast<size_t>(e.src)].name << ','
              << frames_[static_cast<size_t>(e.tgt)].name << ',' << e.num_matches << ',' << e.num_inliers << ','
              << (used ? 1 : 0) << '\n';
    std::string load_error;
    const bool was_resident = e.points_resident;
    if (!edge_store_.Load(&e, &load_error)) {
      spdlog::warn("correspondences.csv: edge {}-{} left out ({})", e.src, e.tgt, load_error);
      continue;
    }
    if (!was_resident && used) engine_.AsSolved(&e);  // the pixels the final solves used (a calibrated lens)
    const Mat3 src_orig = frames_[static_cast<size_t>(e.src)].work_from_original.inverse();
    const Mat3 tgt_orig = frames_[static_cast<size_t>(e.tgt)].work_from_original.inverse();
    char line[160];
    for (size_t k = 0; k < e.src_points.size(); ++k) {
      const Vec2 a = Apply(src_orig, e.src_points[k]);
      const Vec2 b = Apply(tgt_orig, e.tgt_points[k]);
      const int n =
          std::snprintf(line, sizeof(line), "%d,%d,%.7g,%.7g,%.7g,%.7g\n", e.src, e.tgt, a.x(), a.y(), b.x(), b.y());
      corr_csv.Write(std::string_view(line, static_cast<size_t>(std::max(0, n))));
    }
    // The solves are done: the compositor gets the memory (the points stay in edges.bin).
    edge_store_.Release(&e);
  }
  if (!corr_csv.Commit(error)) return false;
  return WriteFileAtomic(paths_.Join("graph.csv"), graph_csv.str(), error);
}

// frames.csv: what the ground tool and georeferencing need per frame; empty cells where metadata is absent.
bool Mosaicker::WriteFramesCsv(const std::unordered_set<int>& in_component, std::string* error) const {
  std::ostringstream frames_csv;
  frames_csv.precision(12);
  frames_csv << "index,filename,stored_file,width,height,timestamp_ns,registered,latitude_deg,longitude_deg,"
                "altitude_m,relative_altitude_m,flight_yaw_deg,gimbal_yaw_deg,gimbal_pitch_deg,focal_length_mm\n";
  const auto cell = [](const std::optional<double>& v) {
    std::ostringstream c;
    c.precision(12);
    if (v) c << *v;
    return c.str();
  };
  for (const auto& f : frames_) {
    const auto& m = f.metadata;
    frames_csv << f.id << ',' << f.name << ',' << std::filesystem::path(f.stored_file).filename().string() << ','
               << f.original_size.width << ',' << f.original_size.height << ',' << f.timestamp_ns << ','
               << (in_component.count(f.id) != 0 ? 1 : 0) << ',' << cell(m.latitude_deg) << ',' << cell(m.longitude_deg)
               << ',' << cell(m.altitude_m) << ',' << cell(m.relative_altitude_m) << ',' << cell(m.flight_yaw_deg)
               << ',' << cell(m.gimbal_yaw_deg) << ',' << cell(m.gimbal_pitch_deg) << ',' << cell(m.focal_length_mm)
               << '\n';
  }
  return WriteFileAtomic(paths_.Join("frames.csv"), frames_csv.str(), error);
}

// The mosaic, tile by tile: mosaic.tiled.tif (MakeProducts() turns it into the COG mosaic.tif) and mosaic.png.
bool Mosaicker::CompositeMosaic(const std::vector<int>& component, const std::vector<Mat3>& canvas_from_original,
                                cv::Size canvas, double scale, CompositeResult* composite, std::string* error) {
  std::vector<CompositeInput> inputs;
  std::unordered_map<int, CanvasLoad> load_of;
  for (int id : component) {
    const FrameState& f = frames_[static_cast<size_t>(id)];
    const Mat3& c = canvas_from_original[static_cast<size_t>(id)];
    // Canvas pixels per original pixel; the frame is loaded at that sampling (never above its own resolution).
    const double local_scale =
        LocalScale(c, Vec2(0.5 * (f.original_size.width - 1), 0.5 * (f.original_size.height - 1)));
    const CanvasLoad how = PlanCanvasLoad(f.stored_file, f.original_size, std::min(1.0, local_scale));
    load_of[id] = how;
    CompositeInput in;
    in.id = id;
    in.image_size = how.size;
    in.load_bytes = how.peak_bytes;
    in.region_loads = how.jpeg;
    in.canvas_from_image = c * ResizeMap(static_cast<double>(how.size.width) / f.original_size.width,
                                         static_cast<double>(how.size.height) / f.original_size.height)
                                   .inverse();
    inputs.push_back(in);
  }
  auto load = [&](int id, const cv::Rect& need) {
    const CanvasLoad& how = load_of.at(id);
    FramePart part = LoadIdealPart(id, how, need);
    CorrectRadiometry(radiometry_, id, how.size, part.origin, &part.image);
    return part;
  };
  GdalTiffWriter tiff;
  const bool write_tiff = options_.write_tiff;
  // The compositor writes a tiled GeoTIFF; MakeProducts() copies it into the COG mosaic.tif.
  if (write_tiff &&
      !tiff.Open(paths_.Join("mosaic.tiled.tif"), canvas, options_.mosaic.tiff_block, options_.mosaic.tile_size,
                 options_.mosaic.build_overviews, options_.mosaic.gdal_cache_mib, error))
    return false;
  *composite = Composite(inputs, canvas, load, options_.mosaic, write_tiff ? &tiff : nullptr);
  if (!composite->ok) {
    *error = "composite failed: " + composite->error;
    return false;
  }
  if (write_tiff && georef_.ok) tiff.SetGeoreference(GdalGeoTransform(georef_.world_from_pixel), georef_.crs_wkt);
  if (write_tiff && !tiff.Close(error)) return false;
  resources_.ComposeEnd();
  std::vector<uchar> png;
  if (!cv::imencode(".png", composite->quicklook, png) ||
      !WriteFileAtomic(paths_.Join("mosaic.png"), std::string(png.begin(), png.end()), error))
    return false;
  spdlog::info(
      "mosaic {}x{} px (scale {:.3f}), {} frames blended, {} dropped by overlap, {} tiles, {} frame loads ({:.0f} ms), "
      "{} parts again from memory, {:.0f} ms",
      canvas.width, canvas.height, scale, composite->frames_used, composite->frames_dropped_by_overlap,
      composite->tiles_written, composite->image_loads, composite->load_ms, composite->reloads_from_memory,
      composite->ms);
  return true;
}

}  // namespace uavm
