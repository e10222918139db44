// Telemetry during the flight: where a new frame's position puts it on the live georeference, for the engine's
// candidates (a PositionHint) when the recent frames fail.
#include <optional>

#include "core/georef/georef.h"
#include "core/pipeline/mosaicker.h"

namespace uavm {

std::optional<PositionHint> Mosaicker::PositionHintFor(const FrameMetadata& m) const {
  if (!live_georef_.ok() || !m.latitude_deg || !m.longitude_deg) return std::nullopt;
  const GeorefFit& fit = live_georef_.fit();
  if (fit.inlier_ids.empty()) return std::nullopt;
  Vec2 world;
  if (!hint_projection_.ToProjected(fit.epsg, *m.latitude_deg, *m.longitude_deg, &world)) return std::nullopt;
  // The fit's pixels are the mosaic coordinates the preview drew its frames in: those of its newest inlier's
  // component (a later merge may have moved it; the hint only chooses candidates, a wrong one costs a few matches).
  return PositionHint{fit.inlier_ids.back(), Apply(WorldFromPixel3(fit.world_from_pixel).inverse(), world)};
}

}  // namespace uavm
