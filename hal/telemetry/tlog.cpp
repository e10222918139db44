#include "hal/telemetry/tlog.h"

#include <array>
#include <cstring>
#include <fstream>
#include <vector>

namespace uavm::hal::mavlink {

namespace {

constexpr size_t kStamp = 8;
constexpr uint64_t kYear2000Us = 946684800ULL * 1000000ULL;
constexpr uint64_t kYear2100Us = 4102444800ULL * 1000000ULL;
constexpr uint64_t kDayUs = 86400ULL * 1000000ULL;

// A sliding window over the file: fixed memory however long the log.
class Window {
 public:
  explicit Window(std::ifstream* in) : in_(in), buf_(1 << 16) {}
  // Makes at least `n` bytes available from the cursor; false at the end of the file.
  bool Have(size_t n) {
    if (end_ - pos_ >= n) return true;
    std::memmove(buf_.data(), buf_.data() + pos_, end_ - pos_);
    end_ -= pos_;
    pos_ = 0;
    while (end_ < n && *in_) {
      in_->read(reinterpret_cast<char*>(buf_.data() + end_), static_cast<std::streamsize>(buf_.size() - end_));
      end_ += static_cast<size_t>(in_->gcount());
    }
    return end_ >= n;
  }
  [[nodiscard]] const uint8_t* at() const { return buf_.data() + pos_; }
  void Skip(size_t n) { pos_ += n; }
  [[nodiscard]] size_t available() const { return end_ - pos_; }

 private:
  std::ifstream* in_;
  std::vector<uint8_t> buf_;
  size_t pos_ = 0;
  size_t end_ = 0;
};

uint64_t BigEndian64(const uint8_t* p) {
  uint64_t v = 0;
  for (size_t i = 0; i < 8; ++i) v = (v << 8) | p[i];
  return v;
}

void Accumulate(ParserCounters* total, const ParserCounters& c) {
  total->packets += c.packets;
  total->unknown += c.unknown;
  total->crc_errors += c.crc_errors;
  total->bytes_skipped += c.bytes_skipped;
  total->signed_packets += c.signed_packets;
  total->unsupported += c.unsupported;
  total->refused_by_signing += c.refused_by_signing;
  total->cut_short += c.cut_short;
}

}  // namespace

bool ReadTlog(const std::string& path, const std::function<void(uint64_t, const Packet&)>& on_packet, TlogStats* stats,
              std::string* error, SignatureCheck* signatures) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *error = "cannot read telemetry log " + path;
    return false;
  }
  *stats = {};
  Window w(&in);
  uint64_t last_us = 0;
  while (w.Have(kStamp + 3)) {
    const uint64_t us = BigEndian64(w.at());
    const uint8_t stx = w.at()[kStamp];
    // A record starts with a time of this century (close to the previous record's) and a start byte.
    const bool plausible = us >= kYear2000Us && us < kYear2100Us && (last_us == 0 || us + kDayUs > last_us) &&
                           (last_us == 0 || us < last_us + kDayUs) && (stx == kStxV1 || stx == kStxV2);
    if (!plausible) {
      w.Skip(1);
      ++stats->resync_bytes;
      continue;
    }
    const size_t frame = mavlink::FrameSize(w.at() + kStamp);
    if (!w.Have(kStamp + frame)) {
      stats->truncated = true;
      break;
    }
    // One record, one packet: a parser of its own, so that damage cannot leak into the next record.
    Parser parser;
    parser.RequireSignatures(signatures);
    bool delivered = false;
    parser.Feed(w.at() + kStamp, frame, [&](const Packet& p) {
      delivered = true;
      on_packet(us, p);
    });
    // A known message, one framed and skipped, or one whose signature was refused.
    const bool framed = parser.counters().packets + parser.counters().refused_by_signing > 0;
    Accumulate(&stats->parser, parser.counters());
    if (framed) {
      stats->records += delivered ? 1 : 0;
      last_us = us;
      w.Skip(kStamp + frame);
      continue;
    }
    // A damaged record: its length may be wrong too, so look for the next record byte by byte.
    w.Skip(1);
    ++stats->resync_bytes;
  }
  if (!stats->truncated && w.available() > 0) stats->truncated = true;
  return true;
}

}  // namespace uavm::hal::mavlink
