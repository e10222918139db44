#include "hal/telemetry/mavlink_signing.h"

#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <fstream>
#include <memory>
#include <optional>

#include "hal/telemetry/mavlink.h"

namespace uavm::hal::mavlink {

namespace {

constexpr size_t kSignatureHash = 6;  // the 48 bits of SHA-256 a frame carries

// SHA-256(key || bytes), its first 48 bits (OpenSSL's EVP digest: the one the live server's TLS uses too); nullopt
// when OpenSSL could not make it (no memory): the frame is then refused, never compared.
std::optional<std::array<uint8_t, kSignatureHash>> Signature(const SigningKey& key, const uint8_t* bytes, size_t size) {
  std::array<uint8_t, EVP_MAX_MD_SIZE> digest{};
  unsigned int digest_size = 0;
  const std::unique_ptr<EVP_MD_CTX, decltype(&EVP_MD_CTX_free)> ctx(EVP_MD_CTX_new(), EVP_MD_CTX_free);
  const bool ok = ctx && EVP_DigestInit_ex(ctx.get(), EVP_sha256(), nullptr) == 1 &&
                  EVP_DigestUpdate(ctx.get(), key.data(), key.size()) == 1 &&
                  EVP_DigestUpdate(ctx.get(), bytes, size) == 1 &&
                  EVP_DigestFinal_ex(ctx.get(), digest.data(), &digest_size) == 1 && digest_size >= kSignatureHash;
  if (!ok) return std::nullopt;
  std::array<uint8_t, kSignatureHash> out{};
  std::copy_n(digest.begin(), kSignatureHash, out.begin());
  return out;
}

int HexDigit(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return c >= 'a' && c <= 'f' ? c - 'a' + 10 : -1;
}

bool ParseHexKey(const std::string& text, SigningKey* key) {
  size_t begin = 0, end = text.size();
  while (begin < end && std::isspace(static_cast<unsigned char>(text[begin]))) ++begin;
  while (end > begin && std::isspace(static_cast<unsigned char>(text[end - 1]))) --end;
  if (end - begin != 2 * key->size()) return false;
  for (size_t i = 0; i < key->size(); ++i) {
    const int hi = HexDigit(text[begin + 2 * i]), lo = HexDigit(text[begin + 2 * i + 1]);
    if (hi < 0 || lo < 0) return false;
    (*key)[i] = static_cast<uint8_t>(hi * 16 + lo);
  }
  return true;
}

}  // namespace

bool ReadSigningKey(const std::string& path, SigningKey* key, std::string* error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *error = "telemetry.signing_key_file " + path + " cannot be read";
    return false;
  }
  std::string text(256, '\0');  // a key file is short: more than this is not a key
  in.read(text.data(), static_cast<std::streamsize>(text.size()));
  text.resize(static_cast<size_t>(in.gcount()));
  SigningKey parsed{};
  // 32 bytes of text (a passphrase of 31 characters and a newline, say) are not a key: a random key is all printable
  // with a probability of (95/256)^32, about 1e-14.
  const bool printable = std::all_of(text.begin(), text.end(), [](char c) {
    return std::isprint(static_cast<unsigned char>(c)) || c == '\n' || c == '\r' || c == '\t';
  });
  if (text.size() == parsed.size() && !printable) {
    std::copy(text.begin(), text.end(), parsed.begin());
  } else if (!ParseHexKey(text, &parsed)) {
    *error = "telemetry.signing_key_file " + path +
             " must hold the 32-byte MAVLink signing key: 32 raw bytes, or 64 hex digits (e.g. `printf %s "
             "PASSPHRASE | sha256sum | cut -c1-64`: the key QGroundControl and MAVProxy make of a passphrase)";
    return false;
  }
  struct stat st {};
  if (stat(path.c_str(), &st) == 0 && (st.st_mode & 077) != 0)
    spdlog::warn("telemetry.signing_key_file {} can be read by other users (mode {:o}): chmod 600 it", path,
                 st.st_mode & 0777);
  *key = parsed;
  return true;
}

uint64_t SigningTimestamp(uint64_t unix_us) {
  return unix_us <= kSigningEpochUnixUs ? 0 : (unix_us - kSigningEpochUnixUs) / 10;
}

std::string Sign(const std::string& unsigned_frame, const SigningKey& key, uint8_t link_id, uint64_t timestamp) {
  std::string out = unsigned_frame;
  auto* b = reinterpret_cast<uint8_t*>(out.data());
  b[2] |= kIncompatSigned;
  const size_t header = 10, length = b[1];
  const uint32_t msgid = b[7] | (b[8] << 8) | (static_cast<uint32_t>(b[9]) << 16);
  const auto info = InfoOf(msgid);
  const uint8_t extra = info ? info->crc_extra : 0;
  uint16_t crc = Crc(b + 1, header - 1 + length);
  crc = Crc(&extra, 1, crc);
  b[header + length] = static_cast<uint8_t>(crc & 0xFF);
  b[header + length + 1] = static_cast<uint8_t>(crc >> 8);
  out.push_back(static_cast<char>(link_id));
  for (int i = 0; i < 6; ++i) out.push_back(static_cast<char>((timestamp >> (8 * i)) & 0xFF));
  // Without a digest the signature stays zero: a frame every receiver refuses, never one signed wrongly on purpose.
  const auto signature = Signature(key, reinterpret_cast<const uint8_t*>(out.data()), out.size());
  out.append(signature ? std::string(signature->begin(), signature->end()) : std::string(kSignatureHash, '\0'));
  return out;
}

SignatureCheck::SignatureCheck(const SigningKey& key) : key_(key) {
  counters_.enabled = true;
}

SignatureVerdict SignatureCheck::Check(const uint8_t* frame, size_t size) {
  const bool is_signed = size > kSignatureBytes && frame[0] == kStxV2 && (frame[2] & kIncompatSigned) != 0;
  if (!is_signed) {
    ++counters_.unsigned_refused;
    return SignatureVerdict::kUnsigned;
  }
  const uint8_t* block = frame + size - kSignatureBytes;
  const auto want = Signature(key_, frame, size - kSignatureHash);
  // Constant time: how many leading bytes matched must not show in the reply time.
  if (!want || CRYPTO_memcmp(want->data(), block + 7, kSignatureHash) != 0) {
    ++counters_.bad_signature;
    return SignatureVerdict::kBadSignature;
  }
  uint64_t timestamp = 0;
  for (int i = 5; i >= 0; --i) timestamp = (timestamp << 8) | block[1 + i];
  const SignatureVerdict verdict = Admit(frame[5], frame[6], block[0], timestamp);
  if (verdict == SignatureVerdict::kAccepted) ++counters_.accepted;
  return verdict;
}

SignatureVerdict SignatureCheck::Admit(uint8_t system, uint8_t component, uint8_t link, uint64_t timestamp) {
  for (size_t i = 0; i < stream_count_; ++i) {
    Stream& s = streams_[i];
    if (s.system != system || s.component != component || s.link != link) continue;
    if (timestamp <= s.timestamp) {
      ++counters_.replayed;
      return SignatureVerdict::kReplayed;
    }
    s.timestamp = timestamp;
    newest_ = std::max(newest_, timestamp);
    return SignatureVerdict::kAccepted;
  }
  const bool too_old = newest_ > kNewStreamWindow && timestamp < newest_ - kNewStreamWindow;
  if (too_old || stream_count_ == streams_.size()) {
    ++counters_.new_stream_refused;
    return SignatureVerdict::kNewStreamRefused;
  }
  streams_[stream_count_++] = {system, component, link, timestamp};
  newest_ = std::max(newest_, timestamp);
  return SignatureVerdict::kAccepted;
}

}  // namespace uavm::hal::mavlink
