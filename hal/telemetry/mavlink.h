#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <variant>

// MAVLink v1/v2 framing and the few messages the mapper uses. Debian 12 packages no MAVLink library, so the decoder is
// ours; it is tested against an independent implementation (node-mavlink, tests/telemetry/). Wire format: the MAVLink
// serialisation guide (mavlink.io): fields sorted by size, little-endian, v2 payloads with trailing zeros cut, an
// X.25 CRC over the header and payload followed by the message's CRC_EXTRA.
namespace uavm::hal::mavlink {

class SignatureCheck;  // hal/telemetry/mavlink_signing.h

inline constexpr uint8_t kStxV1 = 0xFE;
inline constexpr uint8_t kStxV2 = 0xFD;
inline constexpr size_t kMaxPacket = 10 + 255 + 2 + 13;  // v2 header, payload, CRC, signature
inline constexpr uint8_t kIncompatSigned = 0x01;

// Bytes of the whole frame that starts at `header` (STX, length and, for v2, the incompatibility flags: 3 bytes are
// read): header, payload, CRC and, when signed, the signature.
[[nodiscard]] size_t FrameSize(const uint8_t* header);

// CRC-16/MCRF4XX as MAVLink uses it ("X.25"): start 0xFFFF, then Accumulate() each byte.
[[nodiscard]] uint16_t Crc(const uint8_t* data, size_t size, uint16_t crc = 0xFFFF);

// The messages the mapper reads (ids and CRC_EXTRA from common.xml / ardupilotmega.xml).
enum MessageId : uint32_t {
  kHeartbeat = 0,
  kSystemTime = 2,
  kGpsRawInt = 24,
  kAttitude = 30,
  kGlobalPositionInt = 33,
  kCameraFeedback = 180,  // ArduPilot
  kStatustext = 253,
  kCameraImageCaptured = 263,
};
// CRC_EXTRA and the full (untruncated) payload length of a known message; nullopt for others.
struct MessageInfo {
  uint8_t crc_extra;
  uint8_t length;
};
[[nodiscard]] std::optional<MessageInfo> InfoOf(uint32_t msgid);

// One framed packet as read off the wire (payload zero-extended to the message's full length when known).
struct Packet {
  int version = 2;
  uint8_t seq = 0;
  uint8_t sysid = 0;
  uint8_t compid = 0;
  uint32_t msgid = 0;
  uint8_t length = 0;  // on the wire
  bool signed_packet = false;
  std::array<uint8_t, 255> payload{};
};

struct Heartbeat {
  uint32_t custom_mode = 0;
  uint8_t type = 0;
  uint8_t autopilot = 0;
  uint8_t base_mode = 0;
  uint8_t system_status = 0;
};
struct SystemTime {
  uint64_t time_unix_usec = 0;
  uint32_t time_boot_ms = 0;
};
struct GpsRawInt {
  uint64_t time_usec = 0;  // UNIX or since boot, as the autopilot sends it
  double lat_deg = 0, lon_deg = 0;
  double alt_msl_m = 0;
  uint8_t fix_type = 0;  // 0-1 no fix, 2 2-D, 3 3-D, 4+ DGPS/RTK
  uint8_t satellites = 0;
  std::optional<double> h_acc_m;  // v2 extension; absent (or 0) when the receiver does not say
  std::optional<double> v_acc_m;
  std::optional<double> eph;  // HDOP (x1), when known
};
struct GlobalPositionInt {
  uint32_t time_boot_ms = 0;
  double lat_deg = 0, lon_deg = 0;
  double alt_msl_m = 0;
  double relative_alt_m = 0;  // above home (take-off)
  double vx_mps = 0, vy_mps = 0, vz_mps = 0;
  std::optional<double> heading_deg;  // absent when the autopilot does not know (UINT16_MAX)
};
struct Attitude {
  uint32_t time_boot_ms = 0;
  double roll_rad = 0, pitch_rad = 0, yaw_rad = 0;
};
struct CameraFeedback {
  uint64_t time_usec = 0;
  double lat_deg = 0, lon_deg = 0;
  double alt_msl_m = 0, alt_rel_m = 0;
  double roll_deg = 0, pitch_deg = 0, yaw_deg = 0;
  uint16_t image_index = 0;
};
struct CameraImageCaptured {
  uint64_t time_utc_usec = 0;
  uint32_t time_boot_ms = 0;
  double lat_deg = 0, lon_deg = 0;
  double alt_msl_m = 0, relative_alt_m = 0;
  std::array<float, 4> q{};  // w x y z
  int32_t image_index = 0;
  int8_t capture_result = 0;
  std::string file_url;
};
struct Statustext {
  uint8_t severity = 0;
  std::string text;
};

using Message = std::variant<Heartbeat, SystemTime, GpsRawInt, GlobalPositionInt, Attitude, CameraFeedback,
                             CameraImageCaptured, Statustext>;
// The payload of a known message; nullopt for the others (skipped, counted by the caller).
[[nodiscard]] std::optional<Message> Decode(const Packet& packet);

// What the parser met on the wire: what a log line and report.json tell the operator.
struct ParserCounters {
  uint64_t packets = 0;             // valid packets (known or not)
  uint64_t unknown = 0;             // valid framing, message the mapper does not read (CRC not checkable: skipped)
  uint64_t crc_errors = 0;          // known message, bad checksum
  uint64_t bytes_skipped = 0;       // garbage between packets, dropped while resynchronising
  uint64_t signed_packets = 0;      // accepted signed packets (verified only with a signing key: RequireSignatures)
  uint64_t unsupported = 0;         // v2 packets with incompatibility flags this decoder does not know (dropped)
  uint64_t refused_by_signing = 0;  // known messages the signature check refused (its counters say why)
  uint64_t cut_short = 0;           // a datagram ended inside a packet (EndDatagram): the part dropped
};

// Byte-stream framer: feed any chunking of the stream (UDP datagrams, serial reads, a log), get whole packets. After
// garbage or a bad CRC it resynchronises on the next start byte inside what it had buffered, so a packet that follows
// damage is not lost. Fixed memory. Packets of messages the mapper does not read are framed by their length (their
// CRC_EXTRA is not known here, so their CRC cannot be checked) and counted.
class Parser {
 public:
  using Sink = std::function<void(const Packet&)>;
  void Feed(const uint8_t* data, size_t size, const Sink& on_packet);
  [[nodiscard]] const ParserCounters& counters() const { return counters_; }
  // Bytes of an incomplete packet still buffered (a truncated log ends with some).
  [[nodiscard]] size_t pending_bytes() const { return size_; }
  // With a check (borrowed: it outlives the parser, and may outlive it to keep its replay state across parsers), only
  // known messages it accepts are delivered. A refused frame is dropped whole (no resynchronisation inside it: its CRC
  // was right, so its length was).
  void RequireSignatures(SignatureCheck* check) { signature_check_ = check; }
  // UDP carries whole packets in each datagram: what is buffered when one ends is a packet cut short (a truncated
  // signature, say). Dropped and counted, so that it cannot swallow the start of the next datagram's packet.
  void EndDatagram();

 private:
  void Push(uint8_t byte, const Sink& on_packet);
  void Complete(const Sink& on_packet);  // buffer_ holds a whole candidate frame
  void Resync(const Sink& on_packet);    // drop the leading start byte and rescan the rest

  std::array<uint8_t, kMaxPacket> buffer_{};
  size_t size_ = 0;
  Packet packet_;
  ParserCounters counters_;
  SignatureCheck* signature_check_ = nullptr;  // borrowed; null: signatures are not checked
};

// A MAVLink v2 frame for `msgid` with `payload` (trailing zeros cut, as senders do). Returns the bytes to send.
[[nodiscard]] std::string Encode(uint32_t msgid, const uint8_t* payload, size_t size, uint8_t seq, uint8_t sysid,
                                 uint8_t compid);
// A MAVLink v2 frame of one of the messages above: the decoder's field layout, full length and CRC_EXTRA (InfoOf), so
// that Decode() of the framed packet gives the message back (to the wire's resolution: 1e-7 deg, mm, cm/s, cdeg).
// For STATUSTEXT back to the GCS, the simulator's telemetry (hal/sim) and tests. Fields the structs do not carry are
// sent as MAVLink's "unknown" (GPS_RAW_INT epv, vel, cog: UINT16_MAX) or zero; HEARTBEAT says MAVLink version 3.
[[nodiscard]] std::string Encode(const Message& message, uint8_t seq, uint8_t sysid, uint8_t compid);

}  // namespace uavm::hal::mavlink
