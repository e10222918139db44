#include "hal/telemetry/telemetry_config.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <utility>
#include <vector>

#include "core/util/fail.h"
#include "hal/telemetry/mavlink_signing.h"

namespace uavm::hal {

namespace {

constexpr const char* kSigningKeyFile = "signing_key_file";

std::vector<std::pair<const char*, double*>> Keys(TelemetryConfig& c) {
  return {{"latency_ms", &c.latency_ms}, {"max_gap_s", &c.max_gap_s},
          {"max_hold_s", &c.max_hold_s}, {"exif_utc_offset_s", &c.exif_utc_offset_s},
          {"system_id", &c.system_id},   {"component_id", &c.component_id}};
}

}  // namespace

bool TelemetryConfig::Check(std::string* why) const {
  if (!(max_gap_s > 0 && max_gap_s <= 60)) return Fail(why, "telemetry.max_gap_s must be in (0,60]");
  if (!(max_hold_s >= 0 && max_hold_s <= max_gap_s))
    return Fail(why, "telemetry.max_hold_s must be in [0, telemetry.max_gap_s]");
  if (!(std::abs(latency_ms) <= 10000)) return Fail(why, "telemetry.latency_ms must be within +-10000");
  if (!(std::abs(exif_utc_offset_s) <= 14 * 3600))
    return Fail(why, "telemetry.exif_utc_offset_s must be within +-14 h");
  const auto id = [](double v) { return v >= 0 && v <= 255 && v == std::floor(v); };
  if (!id(system_id) || !id(component_id))
    return Fail(why, "telemetry.system_id and component_id must be MAVLink ids in [0, 255] (0 = the first autopilot)");
  if (system_id == 0 && component_id != 0) return Fail(why, "telemetry.component_id needs telemetry.system_id");
  return true;
}

TelemetryOptions TelemetryConfig::ToOptions() const {
  TelemetryOptions o;
  o.latency_ns = static_cast<int64_t>(latency_ms * 1e6);
  o.max_gap_ns = static_cast<int64_t>(max_gap_s * 1e9);
  o.max_hold_ns = static_cast<int64_t>(max_hold_s * 1e9);
  o.exif_utc_offset_s = exif_utc_offset_s;
  o.system_id = static_cast<int>(system_id);
  o.component_id = static_cast<int>(component_id);
  o.signing_key_file = signing_key_file;
  return o;
}

bool ParseTelemetryConfigYaml(const std::string& text, const std::string& origin, TelemetryConfig* config,
                              std::string* error) {
  TelemetryConfig c = *config;
  try {
    const YAML::Node root = YAML::Load(text);
    if (!root.IsMap() || !root[kTelemetrySection]) return true;  // no section: as is (core reports a bad document)
    const YAML::Node section = root[kTelemetrySection];
    if (!section.IsMap()) return Fail(error, "config " + origin + ": 'telemetry' must be a mapping");
    auto keys = Keys(c);
    for (const auto& kv : section) {
      const std::string key = kv.first.as<std::string>();
      if (key == kSigningKeyFile) {
        if (!kv.second.IsScalar()) return Fail(error, "config " + origin + ": 'telemetry." + key + "' must be a path");
        c.signing_key_file = kv.second.as<std::string>();
        continue;
      }
      bool known = false;
      for (auto& [name, value] : keys)
        if (key == name) {
          known = true;
          try {
            *value = kv.second.as<double>();
          } catch (const std::exception&) {
            return Fail(error, "config " + origin + ": 'telemetry." + key + "' has the wrong type");
          }
        }
      if (!known) return Fail(error, "config " + origin + ": unknown key 'telemetry." + key + "'");
    }
  } catch (const std::exception& e) {
    return Fail(error, "config " + origin + ": " + e.what());
  }
  std::string why;
  if (!c.Check(&why)) return Fail(error, "config " + origin + ": " + why);
  mavlink::SigningKey key{};  // read again by the source; a file without a key is the config's error
  if (!c.signing_key_file.empty() && !mavlink::ReadSigningKey(c.signing_key_file, &key, &why))
    return Fail(error, "config " + origin + ": " + why);
  *config = c;
  return true;
}

std::string ToYaml(const TelemetryConfig& config) {
  TelemetryConfig copy = config;
  YAML::Emitter out;
  out << YAML::BeginMap << YAML::Key << kTelemetrySection << YAML::Value << YAML::BeginMap;
  for (const auto& [name, value] : Keys(copy)) out << YAML::Key << name << YAML::Value << *value;
  out << YAML::Key << kSigningKeyFile << YAML::Value << config.signing_key_file;
  out << YAML::EndMap << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

}  // namespace uavm::hal
