// Fuzzes the YAML config parser: any text either loads into options that pass Check() and survive a round trip
// through ToYaml(), or is refused with a message. Never a crash, an abort or an uncaught exception.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "core/pipeline/options.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  uavm::PipelineOptions options;
  std::string error;
  if (!uavm::ParseOptionsYaml(text, "fuzz.yaml", &options, &error)) {
    if (error.empty()) std::abort();  // a refusal always says why
    return 0;
  }
  std::string why;
  if (!options.Check(&why)) std::abort();
  const std::string yaml = uavm::ToYaml(options);
  uavm::PipelineOptions again;
  if (!uavm::ParseOptionsYaml(yaml, "round-trip", &again, &error)) std::abort();
  if (uavm::ToYaml(again) != yaml) std::abort();
  return 0;
}
