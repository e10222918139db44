#include "hal/telemetry/mavlink.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "hal/telemetry/mavlink_signing.h"

namespace uavm::hal::mavlink {

namespace {

constexpr size_t kHeaderV1 = 6;   // STX len seq sys comp msgid
constexpr size_t kHeaderV2 = 10;  // STX len incompat compat seq sys comp msgid[3]

template <typename T>
T Read(const Packet& p, size_t offset) {
  T v;
  std::memcpy(&v, p.payload.data() + offset, sizeof(T));  // little-endian on every target we build for
  return v;
}

double Deg7(int32_t v) {
  return static_cast<double>(v) * 1e-7;
}

std::string Text(const Packet& p, size_t offset, size_t max) {
  const char* begin = reinterpret_cast<const char*>(p.payload.data() + offset);
  return {begin, strnlen(begin, max)};
}

Message DecodeGpsRawInt(const Packet& p) {
  GpsRawInt m;
  m.time_usec = Read<uint64_t>(p, 0);
  m.lat_deg = Deg7(Read<int32_t>(p, 8));
  m.lon_deg = Deg7(Read<int32_t>(p, 12));
  m.alt_msl_m = Read<int32_t>(p, 16) * 1e-3;
  const uint16_t eph = Read<uint16_t>(p, 20);
  if (eph != UINT16_MAX) m.eph = eph * 0.01;
  m.fix_type = p.payload[28];
  m.satellites = p.payload[29];
  // Extensions (MAVLink 2 only; zero when absent): horizontal / vertical accuracy in mm.
  const uint32_t h_acc = Read<uint32_t>(p, 34);
  const uint32_t v_acc = Read<uint32_t>(p, 38);
  if (h_acc > 0) m.h_acc_m = h_acc * 1e-3;
  if (v_acc > 0) m.v_acc_m = v_acc * 1e-3;
  return m;
}

Message DecodeGlobalPositionInt(const Packet& p) {
  GlobalPositionInt m;
  m.time_boot_ms = Read<uint32_t>(p, 0);
  m.lat_deg = Deg7(Read<int32_t>(p, 4));
  m.lon_deg = Deg7(Read<int32_t>(p, 8));
  m.alt_msl_m = Read<int32_t>(p, 12) * 1e-3;
  m.relative_alt_m = Read<int32_t>(p, 16) * 1e-3;
  m.vx_mps = Read<int16_t>(p, 20) * 0.01;
  m.vy_mps = Read<int16_t>(p, 22) * 0.01;
  m.vz_mps = Read<int16_t>(p, 24) * 0.01;
  const uint16_t hdg = Read<uint16_t>(p, 26);
  if (hdg != UINT16_MAX) m.heading_deg = hdg * 0.01;
  return m;
}

Message DecodeCameraFeedback(const Packet& p) {
  CameraFeedback m;
  m.time_usec = Read<uint64_t>(p, 0);
  m.lat_deg = Deg7(Read<int32_t>(p, 8));
  m.lon_deg = Deg7(Read<int32_t>(p, 12));
  m.alt_msl_m = Read<float>(p, 16);
  m.alt_rel_m = Read<float>(p, 20);
  m.roll_deg = Read<float>(p, 24);
  m.pitch_deg = Read<float>(p, 28);
  m.yaw_deg = Read<float>(p, 32);
  m.image_index = Read<uint16_t>(p, 40);
  return m;
}

Message DecodeCameraImageCaptured(const Packet& p) {
  CameraImageCaptured m;
  m.time_utc_usec = Read<uint64_t>(p, 0);
  m.time_boot_ms = Read<uint32_t>(p, 8);
  m.lat_deg = Deg7(Read<int32_t>(p, 12));
  m.lon_deg = Deg7(Read<int32_t>(p, 16));
  m.alt_msl_m = Read<int32_t>(p, 20) * 1e-3;
  m.relative_alt_m = Read<int32_t>(p, 24) * 1e-3;
  for (size_t k = 0; k < 4; ++k) m.q[k] = Read<float>(p, 28 + 4 * k);
  m.image_index = Read<int32_t>(p, 44);
  m.capture_result = static_cast<int8_t>(p.payload[49]);
  m.file_url = Text(p, 50, 205);
  return m;
}

}  // namespace

uint16_t Crc(const uint8_t* data, size_t size, uint16_t crc) {
  for (size_t i = 0; i < size; ++i) {
    uint8_t t = static_cast<uint8_t>(data[i] ^ (crc & 0xFF));
    t = static_cast<uint8_t>(t ^ (t << 4));
    crc = static_cast<uint16_t>((crc >> 8) ^ (t << 8) ^ (t << 3) ^ (t >> 4));
  }
  return crc;
}

std::optional<MessageInfo> InfoOf(uint32_t msgid) {
  switch (msgid) {
    case kHeartbeat:
      return MessageInfo{50, 9};
    case kSystemTime:
      return MessageInfo{137, 12};
    case kGpsRawInt:
      return MessageInfo{24, 52};
    case kAttitude:
      return MessageInfo{39, 28};
    case kGlobalPositionInt:
      return MessageInfo{104, 28};
    case kCameraFeedback:
      return MessageInfo{52, 47};
    case kStatustext:
      return MessageInfo{83, 54};
    case kCameraImageCaptured:
      return MessageInfo{133, 255};
    default:
      return std::nullopt;
  }
}

std::optional<Message> Decode(const Packet& p) {
  switch (p.msgid) {
    case kHeartbeat:
      return Heartbeat{Read<uint32_t>(p, 0), p.payload[4], p.payload[5], p.payload[6], p.payload[7]};
    case kSystemTime:
      return SystemTime{Read<uint64_t>(p, 0), Read<uint32_t>(p, 8)};
    case kGpsRawInt:
      return DecodeGpsRawInt(p);
    case kAttitude:
      return Attitude{Read<uint32_t>(p, 0), Read<float>(p, 4), Read<float>(p, 8), Read<float>(p, 12)};
    case kGlobalPositionInt:
      return DecodeGlobalPositionInt(p);
    case kCameraFeedback:
      return DecodeCameraFeedback(p);
    case kStatustext:
      return Statustext{p.payload[0], Text(p, 1, 50)};
    case kCameraImageCaptured:
      return DecodeCameraImageCaptured(p);
    default:
      return std::nullopt;
  }
}

void Parser::Feed(const uint8_t* data, size_t size, const Sink& on_packet) {
  for (size_t i = 0; i < size; ++i) Push(data[i], on_packet);
}

size_t FrameSize(const uint8_t* p) {
  if (p[0] == kStxV1) return kHeaderV1 + p[1] + 2;
  return kHeaderV2 + p[1] + 2 + ((p[2] & kIncompatSigned) != 0 ? kSignatureBytes : 0);
}

void Parser::Push(uint8_t byte, const Sink& on_packet) {
  if (size_ == 0 && byte != kStxV1 && byte != kStxV2) {
    ++counters_.bytes_skipped;
    return;
  }
  buffer_[size_++] = byte;
  // v1 needs STX and length to know its size, v2 also its flags.
  const size_t known_after = buffer_[0] == kStxV1 ? 2 : 3;
  if (size_ >= known_after && size_ == FrameSize(buffer_.data())) Complete(on_packet);
}

void Parser::Complete(const Sink& on_packet) {
  const bool v1 = buffer_[0] == kStxV1;
  const size_t header = v1 ? kHeaderV1 : kHeaderV2;
  Packet& p = packet_;
  p.version = v1 ? 1 : 2;
  p.length = buffer_[1];
  p.signed_packet = !v1 && (buffer_[2] & kIncompatSigned) != 0;
  p.seq = buffer_[v1 ? 2 : 4];
  p.sysid = buffer_[v1 ? 3 : 5];
  p.compid = buffer_[v1 ? 4 : 6];
  p.msgid = v1 ? buffer_[5] : (buffer_[7] | (buffer_[8] << 8) | (static_cast<uint32_t>(buffer_[9]) << 16));
  if (!v1 && (buffer_[2] & ~kIncompatSigned) != 0) {
    ++counters_.unsupported;  // the spec says to drop what cannot be understood
    size_ = 0;
    return;
  }
  const auto info = InfoOf(p.msgid);
  if (info) {
    uint16_t crc = Crc(buffer_.data() + 1, header - 1 + p.length);
    crc = Crc(&info->crc_extra, 1, crc);
    const uint16_t wire = static_cast<uint16_t>(buffer_[header + p.length] | (buffer_[header + p.length + 1] << 8));
    if (crc != wire) {
      ++counters_.crc_errors;
      Resync(on_packet);
      return;
    }
    if (signature_check_ != nullptr && signature_check_->Check(buffer_.data(), size_) != SignatureVerdict::kAccepted) {
      ++counters_.refused_by_signing;
      size_ = 0;
      return;
    }
  } else {
    ++counters_.unknown;
  }
  p.payload.fill(0);  // MAVLink 2 cuts trailing zero bytes: the rest of the message reads as zeros
  std::copy_n(buffer_.begin() + static_cast<long>(header), p.length, p.payload.begin());
  ++counters_.packets;
  if (p.signed_packet) ++counters_.signed_packets;
  size_ = 0;
  if (info) on_packet(p);
}

void Parser::EndDatagram() {
  if (size_ == 0) return;
  ++counters_.cut_short;
  counters_.bytes_skipped += size_;
  size_ = 0;
}

void Parser::Resync(const Sink& on_packet) {
  // What followed the false start byte may hold the start of a real packet (or a whole one).
  std::array<uint8_t, kMaxPacket> rest{};
  const size_t n = size_ - 1;
  std::copy_n(buffer_.begin() + 1, n, rest.begin());
  size_ = 0;
  ++counters_.bytes_skipped;
  for (size_t i = 0; i < n; ++i) Push(rest[i], on_packet);
}

std::string Encode(uint32_t msgid, const uint8_t* payload, size_t size, uint8_t seq, uint8_t sysid, uint8_t compid) {
  while (size > 1 && payload[size - 1] == 0) --size;  // MAVLink 2 payload truncation (at least one byte stays)
  std::string out(kHeaderV2 + size + 2, '\0');
  auto* b = reinterpret_cast<uint8_t*>(out.data());
  b[0] = kStxV2;
  b[1] = static_cast<uint8_t>(size);
  b[4] = seq;
  b[5] = sysid;
  b[6] = compid;
  b[7] = static_cast<uint8_t>(msgid & 0xFF);
  b[8] = static_cast<uint8_t>((msgid >> 8) & 0xFF);
  b[9] = static_cast<uint8_t>((msgid >> 16) & 0xFF);
  std::copy_n(payload, size, b + kHeaderV2);
  const auto info = InfoOf(msgid);
  uint16_t crc = Crc(b + 1, kHeaderV2 - 1 + size);
  const uint8_t extra = info ? info->crc_extra : 0;
  crc = Crc(&extra, 1, crc);
  b[kHeaderV2 + size] = static_cast<uint8_t>(crc & 0xFF);
  b[kHeaderV2 + size + 1] = static_cast<uint8_t>(crc >> 8);
  return out;
}

namespace {

// A payload being written: the mirror of Read() above, at the same offsets.
struct Writer {
  std::array<uint8_t, 255> bytes{};
  template <typename T>
  void Put(size_t offset, T v) {
    std::memcpy(bytes.data() + offset, &v, sizeof(T));
  }
  void Text(size_t offset, const std::string& text, size_t max) {
    std::memcpy(bytes.data() + offset, text.data(), std::min(text.size(), max));
  }
};

int32_t ToDeg7(double deg) {
  return static_cast<int32_t>(std::llround(deg * 1e7));
}
int32_t ToMm(double m) {
  return static_cast<int32_t>(std::llround(m * 1e3));
}
// A compass angle in [0, 36000) hundredths of a degree.
uint16_t Centidegrees(double deg) {
  const long long c = std::llround((std::fmod(std::fmod(deg, 360.0) + 360.0, 360.0)) * 100.0);
  return static_cast<uint16_t>(c % 36000);
}
template <typename T>
T Scaled(double v, double scale) {
  return static_cast<T>(std::llround(v * scale));
}

void Put(const Heartbeat& m, Writer* w) {
  w->Put<uint32_t>(0, m.custom_mode);
  w->Put<uint8_t>(4, m.type);
  w->Put<uint8_t>(5, m.autopilot);
  w->Put<uint8_t>(6, m.base_mode);
  w->Put<uint8_t>(7, m.system_status);
  w->Put<uint8_t>(8, 3);  // mavlink_version
}
void Put(const SystemTime& m, Writer* w) {
  w->Put<uint64_t>(0, m.time_unix_usec);
  w->Put<uint32_t>(8, m.time_boot_ms);
}
void Put(const GpsRawInt& m, Writer* w) {
  w->Put<uint64_t>(0, m.time_usec);
  w->Put<int32_t>(8, ToDeg7(m.lat_deg));
  w->Put<int32_t>(12, ToDeg7(m.lon_deg));
  w->Put<int32_t>(16, ToMm(m.alt_msl_m));
  w->Put<uint16_t>(20, m.eph ? Scaled<uint16_t>(*m.eph, 100) : UINT16_MAX);
  w->Put<uint16_t>(22, UINT16_MAX);  // epv, vel, cog: unknown
  w->Put<uint16_t>(24, UINT16_MAX);
  w->Put<uint16_t>(26, UINT16_MAX);
  w->Put<uint8_t>(28, m.fix_type);
  w->Put<uint8_t>(29, m.satellites);
  w->Put<uint32_t>(34, m.h_acc_m ? Scaled<uint32_t>(*m.h_acc_m, 1e3) : 0);
  w->Put<uint32_t>(38, m.v_acc_m ? Scaled<uint32_t>(*m.v_acc_m, 1e3) : 0);
}
void Put(const GlobalPositionInt& m, Writer* w) {
  w->Put<uint32_t>(0, m.time_boot_ms);
  w->Put<int32_t>(4, ToDeg7(m.lat_deg));
  w->Put<int32_t>(8, ToDeg7(m.lon_deg));
  w->Put<int32_t>(12, ToMm(m.alt_msl_m));
  w->Put<int32_t>(16, ToMm(m.relative_alt_m));
  w->Put<int16_t>(20, Scaled<int16_t>(m.vx_mps, 100));
  w->Put<int16_t>(22, Scaled<int16_t>(m.vy_mps, 100));
  w->Put<int16_t>(24, Scaled<int16_t>(m.vz_mps, 100));
  w->Put<uint16_t>(26, m.heading_deg ? Centidegrees(*m.heading_deg) : UINT16_MAX);
}
void Put(const Attitude& m, Writer* w) {
  w->Put<uint32_t>(0, m.time_boot_ms);
  w->Put<float>(4, static_cast<float>(m.roll_rad));
  w->Put<float>(8, static_cast<float>(m.pitch_rad));
  w->Put<float>(12, static_cast<float>(m.yaw_rad));
}
void Put(const CameraFeedback& m, Writer* w) {
  w->Put<uint64_t>(0, m.time_usec);
  w->Put<int32_t>(8, ToDeg7(m.lat_deg));
  w->Put<int32_t>(12, ToDeg7(m.lon_deg));
  w->Put<float>(16, static_cast<float>(m.alt_msl_m));
  w->Put<float>(20, static_cast<float>(m.alt_rel_m));
  w->Put<float>(24, static_cast<float>(m.roll_deg));
  w->Put<float>(28, static_cast<float>(m.pitch_deg));
  w->Put<float>(32, static_cast<float>(m.yaw_deg));
  w->Put<uint16_t>(40, m.image_index);
  w->Put<uint16_t>(45, m.image_index);  // completed_captures (extension): one capture per trigger
}
void Put(const CameraImageCaptured& m, Writer* w) {
  w->Put<uint64_t>(0, m.time_utc_usec);
  w->Put<uint32_t>(8, m.time_boot_ms);
  w->Put<int32_t>(12, ToDeg7(m.lat_deg));
  w->Put<int32_t>(16, ToDeg7(m.lon_deg));
  w->Put<int32_t>(20, ToMm(m.alt_msl_m));
  w->Put<int32_t>(24, ToMm(m.relative_alt_m));
  for (size_t k = 0; k < 4; ++k) w->Put<float>(28 + 4 * k, m.q[k]);
  w->Put<int32_t>(44, m.image_index);
  w->Put<int8_t>(49, m.capture_result);
  w->Text(50, m.file_url, 205);
}
void Put(const Statustext& m, Writer* w) {
  w->Put<uint8_t>(0, m.severity);
  w->Text(1, m.text, 50);
}

uint32_t IdOf(const Message& m) {
  static constexpr std::array<uint32_t, std::variant_size_v<Message>> kIds = {
      kHeartbeat, kSystemTime,     kGpsRawInt,           kGlobalPositionInt,
      kAttitude,  kCameraFeedback, kCameraImageCaptured, kStatustext};
  return kIds[m.index()];
}

}  // namespace

std::string Encode(const Message& message, uint8_t seq, uint8_t sysid, uint8_t compid) {
  Writer w;
  std::visit([&w](const auto& m) { Put(m, &w); }, message);
  const uint32_t msgid = IdOf(message);
  return Encode(msgid, w.bytes.data(), InfoOf(msgid)->length, seq, sysid, compid);
}

}  // namespace uavm::hal::mavlink
