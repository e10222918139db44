#pragma once
// A MAVLink signing key as its key file holds it: 64 lower-case hex digits and a newline (what
// `sha256sum | cut -c1-64` writes), for the tests that give a key to the program, the simulator or the node peer.
#include <string>

#include "hal/telemetry/mavlink_signing.h"

namespace uavm::test {

inline std::string HexKeyFileText(const hal::mavlink::SigningKey& key) {
  constexpr char kDigits[] = "0123456789abcdef";
  std::string text;
  for (const uint8_t byte : key) {
    text += kDigits[byte >> 4];
    text += kDigits[byte & 15];
  }
  return text + "\n";
}

}  // namespace uavm::test
