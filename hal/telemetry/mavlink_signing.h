#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <string>

// MAVLink 2 message signing (mavlink.io, "Message Signing"): a signed frame carries 13 bytes after its CRC, a link
// id, a 48-bit timestamp (10 us units since 2015-01-01 UTC) and the first 48 bits of
// SHA-256(secret key || the frame from its start byte to the timestamp). With a key, only frames signed with it are
// taken: a sender without the key (a second vehicle, a GCS of another operator, a spoofer on the Wi-Fi) cannot move
// the map, and a recorded frame sent again is refused by its timestamp.
namespace uavm::hal::mavlink {

using SigningKey = std::array<uint8_t, 32>;
inline constexpr size_t kSignatureBytes = 13;                                // link id, timestamp, signature
inline constexpr uint64_t kSigningEpochUnixUs = 1420070400ULL * 1000000ULL;  // 2015-01-01 00:00:00 UTC
// A new stream (system, component, link) is taken only if its timestamp is at most this far behind the newest
// accepted one (the spec's one minute, in 10 us units): a replay cannot open a stream of its own with old frames.
inline constexpr uint64_t kNewStreamWindow = 60ULL * 100000ULL;

// The 32-byte secret as QGroundControl and MAVProxy hold it (the SHA-256 of the passphrase): a file of exactly 32
// bytes, or of 64 hex digits (whitespace around them allowed). False with the reason otherwise; a file others may
// read is said in the log (it should be 0600).
[[nodiscard]] bool ReadSigningKey(const std::string& path, SigningKey* key, std::string* error);
// 10 us units since 2015-01-01 UTC of a UNIX time in microseconds (0 before 2015).
[[nodiscard]] uint64_t SigningTimestamp(uint64_t unix_us);
// The frame `unsigned_frame` (a whole v2 frame without signature, as Encode() makes it) signed: the signed flag set,
// the CRC computed again over the new header (its CRC_EXTRA from InfoOf(), 0 for others), the signature appended.
[[nodiscard]] std::string Sign(const std::string& unsigned_frame, const SigningKey& key, uint8_t link_id,
                               uint64_t timestamp);

// What signing refused: report.json "telemetry.signing".
struct SigningCounters {
  bool enabled = false;
  uint64_t accepted = 0;
  uint64_t unsigned_refused = 0;    // v1 frames, v2 frames without signature
  uint64_t bad_signature = 0;       // another key, damage after the CRC, a signature cut short
  uint64_t replayed = 0;            // timestamp not newer than the stream's last accepted one
  uint64_t new_stream_refused = 0;  // a new stream too old, or more streams than the table holds
};

enum class SignatureVerdict { kAccepted, kUnsigned, kBadSignature, kReplayed, kNewStreamRefused };

// Checks whole frames against one key and keeps the replay state: the newest accepted timestamp of each stream
// (system, component, link id), in a fixed table. A verdict other than kAccepted is counted. Single-threaded.
class SignatureCheck {
 public:
  static constexpr size_t kMaxStreams = 32;
  explicit SignatureCheck(const SigningKey& key);
  // `frame`: the whole frame as on the wire, `size` bytes (the signature included when flagged).
  [[nodiscard]] SignatureVerdict Check(const uint8_t* frame, size_t size);
  [[nodiscard]] const SigningCounters& counters() const { return counters_; }

 private:
  struct Stream {
    uint8_t system = 0, component = 0, link = 0;
    uint64_t timestamp = 0;
  };
  [[nodiscard]] SignatureVerdict Admit(uint8_t system, uint8_t component, uint8_t link, uint64_t timestamp);

  SigningKey key_;
  std::array<Stream, kMaxStreams> streams_{};
  size_t stream_count_ = 0;
  uint64_t newest_ = 0;  // the newest timestamp accepted from any stream
  SigningCounters counters_;
};

}  // namespace uavm::hal::mavlink
