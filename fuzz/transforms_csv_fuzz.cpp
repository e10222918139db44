// Fuzzes the transforms.csv parser: arbitrary text is parsed or refused with a message; what parses formats back
// into a file that parses to the same rows.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

#include "core/session/session_dir.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  std::vector<uavm::TransformRow> rows;
  std::string error;
  if (!uavm::ParseTransformsCsv(text, &rows, &error)) {
    if (error.empty()) std::abort();
    return 0;
  }
  std::vector<uavm::TransformRow> again;
  if (!uavm::ParseTransformsCsv(uavm::FormatTransformsCsv(rows), &again, &error)) std::abort();
  if (again.size() != rows.size()) std::abort();
  for (size_t i = 0; i < rows.size(); ++i)
    if (again[i].index != rows[i].index || again[i].filename != rows[i].filename ||
        again[i].registered != rows[i].registered)
      std::abort();
  return 0;
}
