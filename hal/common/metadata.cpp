#include "hal/common/metadata.h"

#include <cmath>
#include <exiv2/exiv2.hpp>
#include <functional>

namespace uavm::hal {

namespace {

std::optional<double> Rational(const Exiv2::Value& v, long i) {
  if (v.count() <= i) return std::nullopt;
  const Exiv2::Rational r = v.toRational(i);
  if (r.second == 0) return std::nullopt;
  return static_cast<double>(r.first) / static_cast<double>(r.second);
}

std::optional<double> GpsCoordinate(const Exiv2::ExifData& exif, const char* key, const char* ref_key) {
  const auto it = exif.findKey(Exiv2::ExifKey(key));
  if (it == exif.end() || it->count() < 3) return std::nullopt;
  const auto d = Rational(it->value(), 0);
  const auto m = Rational(it->value(), 1);
  const auto s = Rational(it->value(), 2);
  if (!d || !m || !s) return std::nullopt;
  double deg = *d + *m / 60.0 + *s / 3600.0;
  const auto ref = exif.findKey(Exiv2::ExifKey(ref_key));
  if (ref != exif.end()) {
    const std::string r = ref->toString();
    if (!r.empty() && (r[0] == 'S' || r[0] == 'W')) deg = -deg;
  }
  if (!std::isfinite(deg) || std::abs(deg) > 180.0) return std::nullopt;
  return deg;
}

std::optional<double> ExifNumber(const Exiv2::ExifData& exif, const char* key) {
  const auto it = exif.findKey(Exiv2::ExifKey(key));
  if (it == exif.end() || it->count() < 1) return std::nullopt;
  const double v = static_cast<double>(it->toFloat(0));
  if (!std::isfinite(v)) return std::nullopt;
  return v;
}

std::optional<double> XmpNumber(const Exiv2::XmpData& xmp, const std::string& key) {
  // Matched by key string: no dependence on the namespace prefix being registered in Exiv2's global table.
  for (const auto& datum : xmp) {
    if (datum.key() != key) continue;
    try {
      const std::string s = datum.toString();
      size_t used = 0;
      const double v = std::stod(s, &used);
      if (used == 0 || !std::isfinite(v)) return std::nullopt;
      return v;
    } catch (...) {
      return std::nullopt;
    }
  }
  return std::nullopt;
}

std::string ExifString(const Exiv2::ExifData& exif, const char* key) {
  const auto it = exif.findKey(Exiv2::ExifKey(key));
  return it == exif.end() ? std::string() : it->toString();
}

// Exiv2's logging is muted once: bad metadata is reported by us, once per file, not spammed.
void InitExiv2() {
  static const bool kReady = [] {
    Exiv2::XmpParser::initialize();
    Exiv2::LogMsg::setLevel(Exiv2::LogMsg::mute);
    return true;
  }();
  (void)kReady;
}

// Reads an opened image's EXIF/XMP. Never throws.
FrameMetadata ReadFrom(const std::function<Exiv2::Image::AutoPtr()>& open, std::string* warning) {
  FrameMetadata md;
  try {
    InitExiv2();
    auto image = open();
    if (image.get() == nullptr) return md;
    image->readMetadata();
    const Exiv2::ExifData& exif = image->exifData();
    md.latitude_deg = GpsCoordinate(exif, "Exif.GPSInfo.GPSLatitude", "Exif.GPSInfo.GPSLatitudeRef");
    md.longitude_deg = GpsCoordinate(exif, "Exif.GPSInfo.GPSLongitude", "Exif.GPSInfo.GPSLongitudeRef");
    md.altitude_m = ExifNumber(exif, "Exif.GPSInfo.GPSAltitude");
    if (md.altitude_m) {
      const auto ref = exif.findKey(Exiv2::ExifKey("Exif.GPSInfo.GPSAltitudeRef"));
      if (ref != exif.end() && ref->count() > 0 && ref->toLong(0) == 1) md.altitude_m = -*md.altitude_m;
    }
    md.focal_length_mm = ExifNumber(exif, "Exif.Photo.FocalLength");
    md.focal_length_35mm = ExifNumber(exif, "Exif.Photo.FocalLengthIn35mmFilm");
    md.make = ExifString(exif, "Exif.Image.Make");
    md.model = ExifString(exif, "Exif.Image.Model");
    md.datetime_original = ExifString(exif, "Exif.Photo.DateTimeOriginal");
    const Exiv2::XmpData& xmp = image->xmpData();
    md.relative_altitude_m = XmpNumber(xmp, "Xmp.drone-dji.RelativeAltitude");
    md.flight_yaw_deg = XmpNumber(xmp, "Xmp.drone-dji.FlightYawDegree");
    md.gimbal_yaw_deg = XmpNumber(xmp, "Xmp.drone-dji.GimbalYawDegree");
    md.gimbal_pitch_deg = XmpNumber(xmp, "Xmp.drone-dji.GimbalPitchDegree");
  } catch (const std::exception& e) {
    if (warning != nullptr) *warning = e.what();
    return FrameMetadata{};
  } catch (...) {
    if (warning != nullptr) *warning = "unreadable metadata";
    return FrameMetadata{};
  }
  return md;
}

}  // namespace

FrameMetadata ReadMetadata(const std::string& path, std::string* warning) {
  return ReadFrom([&] { return Exiv2::ImageFactory::open(path); }, warning);
}

FrameMetadata ReadMetadata(const unsigned char* data, size_t size, std::string* warning) {
  if (data == nullptr || size == 0) return {};
  // Only the formats frames come in (hal/replay reads nothing else): Exiv2's parsers of raw, video and other
  // formats are never given untrusted bytes.
  return ReadFrom(
      [&]() -> Exiv2::Image::AutoPtr {
        const int type = Exiv2::ImageFactory::getType(data, static_cast<long>(size));
        if (type != Exiv2::ImageType::jpeg && type != Exiv2::ImageType::png && type != Exiv2::ImageType::tiff)
          return Exiv2::Image::AutoPtr();
        return Exiv2::ImageFactory::open(data, static_cast<long>(size));
      },
      warning);
}

}  // namespace uavm::hal
