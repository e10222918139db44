// Fuzzes the session journal reader (journal.jsonl, read by --resume): arbitrary text is parsed or refused with a
// message, never trusted beyond its well-formed prefix; a frame it accepts is safe to open inside frames/.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "core/session/journal.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  uavm::JournalContents contents;
  std::string error;
  if (!uavm::ParseJournal(text, &contents, &error)) {
    if (error.empty()) std::abort();
    return 0;
  }
  if (contents.valid_bytes > size) std::abort();
  for (size_t i = 0; i < contents.frames.size(); ++i) {
    const auto& f = contents.frames[i];
    if (f.id != static_cast<int>(i) || f.width <= 0 || f.height <= 0) std::abort();
    if (f.stored_file.empty() || f.stored_file.find('/') != std::string::npos) std::abort();
  }
  return 0;
}
