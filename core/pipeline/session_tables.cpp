#include "core/pipeline/session_tables.h"

#include <fmt/format.h>

#include <filesystem>
#include <optional>

#include "core/session/session_dir.h"
#include "core/util/memory.h"

namespace uavm {

bool WriteTransformsCsv(const std::string& path, const FlightRecord& record, const IdSet& in_map,
                        const std::vector<Mat3>& canvas_from_original, const std::unordered_set<int>& by_telemetry,
                        std::string* error) {
  // Streamed row by row like frames.csv: the rows and the whole text were ~2 MB of a 5000-frame flight's outputs.
  AtomicFileWriter transforms_csv;
  if (!transforms_csv.Open(path, error)) return false;
  transforms_csv.Write(std::string(kTransformsHeader) + "\n");
  TransformRow r;
  for (const auto& f : record.frames()) {
    r.index = f.id;
    r.filename = f.name;
    r.registered = in_map.contains(f.id);
    r.mosaic_from_frame = canvas_from_original[static_cast<size_t>(f.id)];
    r.placed_by = !r.registered ? "" : by_telemetry.count(f.id) != 0 ? "telemetry" : "image";
    transforms_csv.Write(FormatTransformsRow(r));
  }
  return transforms_csv.Commit(error);
}

bool WriteFramesCsv(const std::string& path, const FlightRecord& record, const IdSet& in_map, std::string* error) {
  // Streamed row by row: the table grows with the flight.
  AtomicFileWriter frames_csv;
  if (!frames_csv.Open(path, error)) return false;
  frames_csv.Write(
      "index,filename,stored_file,width,height,timestamp_ns,registered,latitude_deg,longitude_deg,altitude_m,"
      "relative_altitude_m,flight_yaw_deg,gimbal_yaw_deg,gimbal_pitch_deg,focal_length_mm\n");
  const auto cell = [](const std::optional<double>& v) { return v ? fmt::format("{:.12g}", *v) : std::string(); };
  for (const auto& f : record.frames()) {
    const auto& m = f.metadata();
    frames_csv.Write(fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", f.id, f.name,
                                 std::filesystem::path(f.stored_file).filename().string(), f.original_size.width,
                                 f.original_size.height, f.timestamp_ns, in_map.contains(f.id) ? 1 : 0,
                                 cell(m.latitude_deg), cell(m.longitude_deg), cell(m.altitude_m),
                                 cell(m.relative_altitude_m), cell(m.flight_yaw_deg), cell(m.gimbal_yaw_deg),
                                 cell(m.gimbal_pitch_deg), cell(m.focal_length_mm)));
  }
  return frames_csv.Commit(error);
}

}  // namespace uavm
