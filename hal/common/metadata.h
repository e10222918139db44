#pragma once
#include <cstddef>
#include <string>

#include "core/frame/frame.h"

namespace uavm::hal {

// The data type lives in core (core/frame/frame.h); this name keeps hal's users unchanged.
using FrameMetadata = ::uavm::FrameMetadata;

// Reads EXIF/XMP with Exiv2. Never throws: unreadable or garbage metadata gives an empty result and, when `warning`
// is given, a one-line reason.
[[nodiscard]] FrameMetadata ReadMetadata(const std::string& path, std::string* warning = nullptr);
// The same from the bytes of an image file already in memory.
[[nodiscard]] FrameMetadata ReadMetadata(const unsigned char* data, size_t size, std::string* warning = nullptr);

}  // namespace uavm::hal
