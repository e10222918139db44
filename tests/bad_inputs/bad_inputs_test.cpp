// Bad-input corpus: the real uavmosaic-onboard on a replay of three good frames of brighton_beach_small plus one
// bad input (or with a bad config, output folder or source). Every case has a documented outcome
// (tests/bad_inputs/README.md): the input is skipped and reported, or used, or decoded but left unregistered, or the
// run stops with a specific exit code and a clear message. Never a signal death, never a hang, and whatever the run
// wrote must still parse. The bad inputs are made here, from the good frames, with OpenCV and byte surgery.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <jpeglib.h>
#include <signal.h>
#include <sys/mount.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "core/session/journal.h"
#include "core/session/session_dir.h"
#include "tests/test_env.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;
using Bytes = std::vector<uchar>;

const std::string kData = UAVM_TEST_DATA;
const std::string kImages = kData + "/brighton_beach_small/images";
// Three consecutive frames that overlap well (123 and 257 inliers, tests/data/.../consecutive_overlap.txt); under
// emulation the first two (each good frame costs a SIFT pass under qemu, in every case of the corpus).
const std::vector<std::string> kGood = test::Emulated()
                                           ? std::vector<std::string>{"DJI_0023.JPG", "DJI_0024.JPG"}
                                           : std::vector<std::string>{"DJI_0023.JPG", "DJI_0024.JPG", "DJI_0025.JPG"};

// What a case expects (README.md of this folder lists them all).
enum class Outcome {
  kSkipped,       // exit 0, the good frames registered, report.json "skipped" lists the bad file with a reason
  kUsable,        // exit 0, the bad-looking input is decoded and registered like a good frame
  kUnregistered,  // exit 0, decoded but not in the mosaic: report.json "unregistered" lists it with a reason
  kExit,          // the run stops with `exit_code` and says `message`
};

struct Env {
  fs::path root;  // everything of the case lives here
  fs::path in;    // the replay folder, holding the good frames
  fs::path out;   // the session directory
  std::string source;
  std::vector<std::string> args;              // more command-line arguments
  std::string bad;                            // file name of the bad input in `in`
  int good = static_cast<int>(kGood.size());  // frames expected registered besides the bad one
  rlim_t fsize_limit = 0;                     // RLIMIT_FSIZE of the program (0 = none): a full disk
  bool remove_source_mid_run = false;
  std::shared_ptr<SessionLock> held;  // a lock on `out` held by the test during the run (another run's)
};

struct Case {
  std::string name;
  Outcome outcome;
  int exit_code;        // kExit only
  std::string message;  // kExit: in the log; kSkipped / kUnregistered: in the reason
  std::function<void(Env&)> setup;
};

// ---- making bad inputs ------------------------------------------------------------------------------------------

Bytes ReadBytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return Bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void WriteBytes(const fs::path& p, const Bytes& b) {
  std::ofstream out(p, std::ios::binary);
  out.write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
}

void WriteText(const fs::path& p, const std::string& s) {
  std::ofstream(p, std::ios::binary) << s;
}

Bytes GoodBytes(const std::string& name = "DJI_0024.JPG") {
  return ReadBytes(kImages + "/" + name);
}
cv::Mat GoodImage(const std::string& name = "DJI_0024.JPG") {
  return cv::imread(kImages + "/" + name);
}

Bytes Encode(const std::string& ext, const cv::Mat& image, const std::vector<int>& params = {}) {
  Bytes b;
  EXPECT_TRUE(cv::imencode(ext, image, b, params)) << ext;
  return b;
}

// Offset of the first JPEG segment with `marker` (the 0xFF byte), or npos.
size_t FindJpegSegment(const Bytes& b, uchar marker) {
  for (size_t i = 2; i + 4 <= b.size();) {
    if (b[i] != 0xFF) return std::string::npos;
    if (b[i + 1] == marker) return i;
    if (b[i + 1] == 0xDA) return std::string::npos;
    i += 2 + (static_cast<size_t>(b[i + 2]) << 8 | b[i + 3]);
  }
  return std::string::npos;
}

// Overwrites [from, to) with seeded noise (no 0xFF, so that no marker appears).
void Scramble(Bytes* b, size_t from, size_t to, unsigned seed) {
  std::mt19937 rng(seed);
  for (size_t i = from; i < to && i < b->size(); ++i) (*b)[i] = static_cast<uchar>(rng() % 255);
}

uint32_t Crc32(const uchar* p, size_t n) {
  uint32_t c = 0xFFFFFFFFu;
  for (size_t i = 0; i < n; ++i) {
    c ^= p[i];
    for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
  }
  return ~c;
}

void PutBe32(Bytes* b, uint32_t v) {
  for (int s = 24; s >= 0; s -= 8) b->push_back(static_cast<uchar>(v >> s));
}

void PngChunk(Bytes* png, const char* type, const Bytes& data) {
  PutBe32(png, static_cast<uint32_t>(data.size()));
  Bytes body(type, type + 4);
  body.insert(body.end(), data.begin(), data.end());
  png->insert(png->end(), body.begin(), body.end());
  PutBe32(png, Crc32(body.data(), body.size()));
}

// A valid little PNG whose header declares width x height (a decompression bomb when large).
Bytes PngDeclaring(uint32_t width, uint32_t height) {
  Bytes png = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  Bytes ihdr;
  PutBe32(&ihdr, width);
  PutBe32(&ihdr, height);
  ihdr.insert(ihdr.end(), {8, 2, 0, 0, 0});  // 8-bit RGB, deflate, no filter, no interlace
  PngChunk(&png, "IHDR", ihdr);
  // A stored (uncompressed) deflate block of 16 zero bytes: far too little data for the declared size.
  Bytes idat = {0x78, 0x01, 0x01, 0x10, 0x00, 0xEF, 0xFF};
  idat.resize(idat.size() + 16, 0);
  PngChunk(&png, "IDAT", idat);
  PngChunk(&png, "IEND", {});
  return png;
}

// A JPEG in Adobe CMYK (what print workflows write): channels stored inverted, as libjpeg and OpenCV expect.
Bytes CmykJpeg(const cv::Mat& bgr) {
  jpeg_compress_struct cinfo{};
  jpeg_error_mgr jerr{};
  cinfo.err = jpeg_std_error(&jerr);
  jpeg_create_compress(&cinfo);
  unsigned char* buffer = nullptr;
  unsigned long size = 0;
  jpeg_mem_dest(&cinfo, &buffer, &size);
  cinfo.image_width = static_cast<JDIMENSION>(bgr.cols);
  cinfo.image_height = static_cast<JDIMENSION>(bgr.rows);
  cinfo.input_components = 4;
  cinfo.in_color_space = JCS_CMYK;
  jpeg_set_defaults(&cinfo);
  jpeg_set_quality(&cinfo, 90, TRUE);
  jpeg_start_compress(&cinfo, TRUE);
  std::vector<uchar> row(static_cast<size_t>(bgr.cols) * 4);
  while (cinfo.next_scanline < cinfo.image_height) {
    const auto* p = bgr.ptr<cv::Vec3b>(static_cast<int>(cinfo.next_scanline));
    for (int x = 0; x < bgr.cols; ++x) {
      // K = 0; inverted C, M, Y are then simply R, G, B.
      const size_t o = static_cast<size_t>(x) * 4;
      row[o] = p[x][2];
      row[o + 1] = p[x][1];
      row[o + 2] = p[x][0];
      row[o + 3] = 255;
    }
    JSAMPROW rows[1] = {row.data()};
    jpeg_write_scanlines(&cinfo, rows, 1);
  }
  jpeg_finish_compress(&cinfo);
  Bytes out(buffer, buffer + size);
  jpeg_destroy_compress(&cinfo);
  std::free(buffer);
  return out;
}

void CopyGood(const Env& env, const std::vector<std::string>& names) {
  for (const auto& n : names) fs::copy_file(kImages + "/" + n, env.in / n, fs::copy_options::overwrite_existing);
}

// Puts a bad input between the first and the second good frame (natural order: DJI_0023, DJI_0023b, DJI_0024...).
void AddBad(Env& env, const std::string& name, const Bytes& bytes) {
  env.bad = name;
  WriteBytes(env.in / name, bytes);
}

// Replaces the second good frame by a converted copy of itself (a usable input must register like the original).
void ReplaceMiddle(Env& env, const std::string& name, const Bytes& bytes) {
  fs::remove(env.in / kGood[1]);
  env.good = static_cast<int>(kGood.size()) - 1;
  AddBad(env, name, bytes);
}

void Config(Env& env, const std::string& yaml) {
  WriteText(env.root / "config.yaml", yaml);
  env.args.insert(env.args.end(), {"--config", (env.root / "config.yaml").string()});
}

// ---- the cases ----------------------------------------------------------------------------------------------------

std::vector<Case> Cases() {
  using O = Outcome;
  std::vector<Case> c;
  // Damaged files.
  c.push_back({"ZeroByteFile", O::kSkipped, 0, "empty file", [](Env& e) { AddBad(e, "DJI_0023b.JPG", {}); }});
  c.push_back({"TruncatedJpeg", O::kSkipped, 0, "truncated", [](Env& e) {
                 Bytes b = GoodBytes();
                 b.resize(b.size() * 6 / 10);
                 AddBad(e, "DJI_0023b.JPG", b);
               }});
  c.push_back({"TruncatedJpegInHeaders", O::kSkipped, 0, "unreadable image header", [](Env& e) {
                 Bytes b = GoodBytes();
                 b.resize(300);
                 AddBad(e, "DJI_0023b.JPG", b);
               }});
  c.push_back({"JpegWithoutScan", O::kSkipped, 0, "corrupt JPEG data", [](Env& e) {
                 Bytes b = GoodBytes();
                 const size_t sos = FindJpegSegment(b, 0xC4);  // keep everything before the tables, then EOI
                 ASSERT_NE(sos, std::string::npos);
                 b.resize(sos);
                 b.insert(b.end(), {0xFF, 0xD9});
                 AddBad(e, "DJI_0023b.JPG", b);
               }});
  c.push_back({"CorruptJpegEntropyData", O::kSkipped, 0, "corrupt JPEG data", [](Env& e) {
                 Bytes b = GoodBytes();
                 Scramble(&b, b.size() * 3 / 10, b.size() * 6 / 10, 1);
                 AddBad(e, "DJI_0023b.JPG", b);
               }});
  c.push_back({"RandomBytesNamedJpg", O::kSkipped, 0, "not a JPEG, PNG or TIFF", [](Env& e) {
                 Bytes b(100000);
                 Scramble(&b, 0, b.size(), 2);
                 AddBad(e, "DJI_0023b.JPG", b);
               }});
  c.push_back({"TextFileNamedJpg", O::kSkipped, 0, "not a JPEG, PNG or TIFF", [](Env& e) {
                 e.bad = "DJI_0023b.JPG";
                 WriteText(e.in / e.bad, "flight log, not an image\n");
               }});
  c.push_back({"PngWithBadCrc", O::kSkipped, 0, "not a decodable image", [](Env& e) {
                 Bytes b = Encode(".png", GoodImage());
                 const auto it = std::search(b.begin(), b.end(), std::begin("IDAT"), std::end("IDAT") - 1);
                 ASSERT_NE(it, b.end());
                 const size_t type = static_cast<size_t>(it - b.begin());
                 const size_t len = static_cast<size_t>(b[type - 4]) << 24 | static_cast<size_t>(b[type - 3]) << 16 |
                                    static_cast<size_t>(b[type - 2]) << 8 | b[type - 1];
                 b[type + 4 + len] ^= 0x5A;  // first byte of the chunk's CRC
                 AddBad(e, "DJI_0023b.png", b);
               }});
  c.push_back({"TruncatedPng", O::kSkipped, 0, "not a decodable image", [](Env& e) {
                 Bytes b = Encode(".png", GoodImage());
                 b.resize(b.size() / 2);
                 AddBad(e, "DJI_0023b.png", b);
               }});
  c.push_back({"DanglingSymlink", O::kSkipped, 0, "cannot read", [](Env& e) {
                 e.bad = "DJI_0023b.JPG";
                 fs::create_symlink(e.root / "nowhere.jpg", e.in / e.bad);
               }});
  c.push_back({"UnsupportedFormatPpm", O::kSkipped, 0, "unsupported format",
               [](Env& e) { AddBad(e, "DJI_0023b.ppm", Encode(".ppm", GoodImage())); }});
  // Sizes.
  c.push_back({"OneByOnePixel", O::kSkipped, 0, "too small", [](Env& e) {
                 AddBad(e, "DJI_0023b.png", Encode(".png", cv::Mat(1, 1, CV_8UC3, cv::Scalar(10, 20, 30))));
               }});
  c.push_back({"Strip100000x10", O::kSkipped, 0, "too small", [](Env& e) {
                 cv::Mat strip;
                 cv::resize(GoodImage(), strip, cv::Size(100000, 10), 0, 0, cv::INTER_AREA);
                 AddBad(e, "DJI_0023b.png", Encode(".png", strip));
               }});
  c.push_back({"PngBomb60000x60000", O::kSkipped, 0, "declares 60000x60000",
               [](Env& e) { AddBad(e, "DJI_0023b.png", PngDeclaring(60000, 60000)); }});
  c.push_back({"PngBomb30000x30000", O::kSkipped, 0, "declares 30000x30000", [](Env& e) {
                 // 900 Mpx: under OpenCV's own 1 Gpx limit, 2.7 GB once decoded.
                 AddBad(e, "DJI_0023b.png", PngDeclaring(30000, 30000));
               }});
  c.push_back({"JpegBomb60000x60000", O::kSkipped, 0, "declares 60000x60000", [](Env& e) {
                 Bytes b = GoodBytes();
                 const size_t sof = FindJpegSegment(b, 0xC0);
                 ASSERT_NE(sof, std::string::npos);
                 for (size_t k : {5u, 7u}) {
                   b[sof + k] = 60000 >> 8;
                   b[sof + k + 1] = 60000 & 0xFF;
                 }
                 AddBad(e, "DJI_0023b.JPG", b);
               }});
  // Pixel formats: converted to 8-bit BGR and used.
  c.push_back({"Png16Bit", O::kUsable, 0, "", [](Env& e) {
                 cv::Mat wide;
                 GoodImage().convertTo(wide, CV_16UC3, 257.0);
                 ReplaceMiddle(e, "DJI_0024.png", Encode(".png", wide));
               }});
  c.push_back({"Tiff16Bit", O::kUsable, 0, "", [](Env& e) {
                 cv::Mat wide;
                 GoodImage().convertTo(wide, CV_16UC3, 257.0);
                 ReplaceMiddle(e, "DJI_0024.tif", Encode(".tif", wide));
               }});
  c.push_back({"GreyJpeg", O::kUsable, 0, "", [](Env& e) {
                 cv::Mat grey;
                 cv::cvtColor(GoodImage(), grey, cv::COLOR_BGR2GRAY);
                 ReplaceMiddle(e, "DJI_0024.JPG", Encode(".jpg", grey, {cv::IMWRITE_JPEG_QUALITY, 92}));
               }});
  c.push_back({"GreyPng", O::kUsable, 0, "", [](Env& e) {
                 cv::Mat grey;
                 cv::cvtColor(GoodImage(), grey, cv::COLOR_BGR2GRAY);
                 ReplaceMiddle(e, "DJI_0024.png", Encode(".png", grey));
               }});
  c.push_back({"BgraPng", O::kUsable, 0, "", [](Env& e) {
                 cv::Mat bgra;
                 cv::cvtColor(GoodImage(), bgra, cv::COLOR_BGR2BGRA);
                 bgra(cv::Rect(0, 0, bgra.cols / 3, bgra.rows)).setTo(cv::Scalar(0, 0, 0, 0));  // a transparent third
                 ReplaceMiddle(e, "DJI_0024.png", Encode(".png", bgra));
               }});
  c.push_back({"CmykJpeg", O::kUsable, 0, "", [](Env& e) { ReplaceMiddle(e, "DJI_0024.JPG", CmykJpeg(GoodImage())); }});
  c.push_back({"PngNamedJpg", O::kUsable, 0, "",
               [](Env& e) { ReplaceMiddle(e, "DJI_0024.JPG", Encode(".png", GoodImage())); }});
  c.push_back({"GarbageExif", O::kUsable, 0, "", [](Env& e) {
                 Bytes b = GoodBytes();
                 const size_t app1 = FindJpegSegment(b, 0xE1);
                 ASSERT_NE(app1, std::string::npos);
                 ASSERT_EQ(
                     std::string(b.begin() + static_cast<long>(app1) + 4, b.begin() + static_cast<long>(app1) + 8),
                     "Exif");
                 const size_t len = static_cast<size_t>(b[app1 + 2]) << 8 | b[app1 + 3];
                 Scramble(&b, app1 + 14, app1 + 2 + len, 3);  // keep "Exif\0\0II*\0", garbage IFDs
                 ReplaceMiddle(e, "DJI_0024.JPG", b);
               }});
  c.push_back({"GarbageXmp", O::kUsable, 0, "", [](Env& e) {
                 Bytes b = GoodBytes();
                 const std::string ns = "http://ns.adobe.com/xap/1.0/";
                 const auto it = std::search(b.begin(), b.end(), ns.begin(), ns.end());
                 ASSERT_NE(it, b.end());
                 const size_t start = static_cast<size_t>(it - b.begin()) + ns.size() + 1;
                 const size_t app1 = start - ns.size() - 1 - 4;
                 const size_t end = app1 + 2 + (static_cast<size_t>(b[app1 + 2]) << 8 | b[app1 + 3]);
                 const std::string junk = "<x:xmpmeta <<rdf:RDF drone-dji:RelativeAltitude=\"+1e999\" &bogus; ]]>";
                 for (size_t i = start; i < end; ++i) b[i] = static_cast<uchar>(junk[(i - start) % junk.size()]);
                 ReplaceMiddle(e, "DJI_0024.JPG", b);
               }});
  // Content that cannot be registered.
  c.push_back({"AllBlackFrame", O::kSkipped, 0, "uniform frame", [](Env& e) {
                 AddBad(e, "DJI_0023b.JPG", Encode(".jpg", cv::Mat(562, 1000, CV_8UC3, cv::Scalar::all(0))));
               }});
  c.push_back({"SaturatedFrame", O::kSkipped, 0, "uniform frame", [](Env& e) {
                 AddBad(e, "DJI_0023b.JPG", Encode(".jpg", cv::Mat(562, 1000, CV_8UC3, cv::Scalar::all(255))));
               }});
  c.push_back({"UniformGreyFrame", O::kSkipped, 0, "uniform frame", [](Env& e) {
                 AddBad(e, "DJI_0023b.JPG", Encode(".jpg", cv::Mat(562, 1000, CV_8UC3, cv::Scalar(90, 120, 110))));
               }});
  c.push_back({"FrameFromAnotherPlace", O::kUnregistered, 0, "", [](Env& e) {
                 e.bad = "DJI_0023b.JPG";
                 fs::copy_file(
                     kData + "/caliterra_small/images/" +
                         fs::directory_iterator(kData + "/caliterra_small/images")->path().filename().string(),
                     e.in / e.bad);
               }});
  c.push_back({"DuplicatedFrame", O::kSkipped, 0, "duplicate of DJI_0024.JPG", [](Env& e) {
                 e.bad = "DJI_0024b.JPG";
                 fs::copy_file(kImages + "/DJI_0024.JPG", e.in / e.bad);
               }});
  c.push_back({"OnlyBadInputs", O::kExit, 5, "", [](Env& e) {
                 for (const auto& n : kGood) fs::remove(e.in / n);
                 WriteText(e.in / "a.JPG", "not an image");
                 WriteBytes(e.in / "b.JPG", {});
               }});
  c.push_back({"OnlyBlackFrames", O::kExit, 5, "", [](Env& e) {
                 for (const auto& n : kGood) fs::remove(e.in / n);
                 for (int k = 0; k < 3; ++k)
                   WriteBytes(e.in / ("black" + std::to_string(k) + ".JPG"),
                              Encode(".jpg", cv::Mat(562, 1000, CV_8UC3, cv::Scalar::all(k))));
               }});
  // Configuration: exit 2 with the reason.
  c.push_back({"ConfigNegativeSize", O::kExit, 2, "work_long_side must be in",
               [](Env& e) { Config(e, "work_long_side: -1000\n"); }});
  c.push_back({"ConfigNegativeNestedSize", O::kExit, 2, "tile_size",
               [](Env& e) { Config(e, "mosaic:\n  tile_size: -512\n"); }});
  c.push_back({"CommandLineNegativeSize", O::kExit, 2, "work_long_side must be in", [](Env& e) {
                 e.args.insert(e.args.end(), {"--work-size", "-5"});
               }});
  c.push_back({"CommandLineNotANumber", O::kExit, 2, "--max-features", [](Env& e) {
                 e.args.insert(e.args.end(), {"--max-features", "lots"});
               }});
  c.push_back({"ConfigUnknownKey", O::kExit, 2, "unknown key 'matching.ratoi'",
               [](Env& e) { Config(e, "matching:\n  ratoi: 0.8\n"); }});
  c.push_back({"ConfigWrongType", O::kExit, 2, "'work_long_side' has the wrong type",
               [](Env& e) { Config(e, "work_long_side: big\n"); }});
  c.push_back(
      {"ConfigWrongModel", O::kExit, 2, "must be affine or homography", [](Env& e) { Config(e, "model: cubic\n"); }});
  c.push_back({"ConfigSectionNotAMapping", O::kExit, 2, "'features' must be a mapping",
               [](Env& e) { Config(e, "features: 3000\n"); }});
  c.push_back({"ConfigNotAMapping", O::kExit, 2, "top level must be a mapping",
               [](Env& e) { Config(e, "- work_long_side\n- 800\n"); }});
  c.push_back({"ConfigSequenceAsKey", O::kExit, 2, "bad conversion", [](Env& e) { Config(e, "? [a, b]\n: 1\n"); }});
  c.push_back(
      {"ConfigYamlSyntaxError", O::kExit, 2, "config", [](Env& e) { Config(e, "features: {max_features: [\n"); }});
  c.push_back({"ConfigBinaryGarbage", O::kExit, 2, "config", [](Env& e) {
                 Bytes b(4096);
                 Scramble(&b, 0, b.size(), 4);
                 WriteBytes(e.root / "config.yaml", b);
                 e.args.insert(e.args.end(), {"--config", (e.root / "config.yaml").string()});
               }});
  c.push_back({"ConfigMissingFile", O::kExit, 2, "config", [](Env& e) {
                 e.args.insert(e.args.end(), {"--config", (e.root / "missing.yaml").string()});
               }});
  // An empty config is the defaults (documented in README.md): the run goes on.
  c.push_back({"ConfigEmptyFile", O::kExit, 0, "", [](Env& e) { Config(e, ""); }});
  // Output.
  c.push_back({"OutputIsAFile", O::kExit, 4, "cannot create output directory", [](Env& e) {
                 WriteText(e.root / "out_file", "x");
                 e.out = e.root / "out_file";
               }});
  c.push_back({"OutputUnderAFile", O::kExit, 4, "cannot create output directory", [](Env& e) {
                 WriteText(e.root / "out_file", "x");
                 e.out = e.root / "out_file" / "session";
               }});
  c.push_back({"OutputInUseByAnotherRun", O::kExit, 4, "is in use by process", [](Env& e) {
                 SessionPaths paths;
                 std::string err;
                 ASSERT_TRUE(PrepareSessionDir(e.out.string(), &paths, &err)) << err;
                 e.held = std::make_shared<SessionLock>();
                 ASSERT_TRUE(e.held->Acquire(paths, &err)) << err;
               }});
  c.push_back({"OutputInReadOnlyFilesystem", O::kExit, 4, "output", [](Env& e) { e.out = "/proc/uavm_session"; }});
  c.push_back({"DiskFullAtFirstFrame", O::kExit, 4, "disk full", [](Env& e) { e.fsize_limit = 64 << 10; }});
  c.push_back({"DiskFullWritingTheMosaic", O::kExit, 4, "output not writable or disk full", [](Env& e) {
                 // Frames and features fit, the 3-frame mosaic does not: mosaic.tif (about 1.3 MB) and the quick-look's
                 // raw file made beside mosaic.png (~3 MB, the first to fail); under emulation the 2-frame mosaic at
                 // the smaller working size is 0.6 MB, its frames up to 0.3 MB.
                 e.fsize_limit = test::Emulated() ? 400 << 10 : 700 << 10;
                 std::erase(e.args, std::string("--no-tiff"));
               }});
  // Source.
  c.push_back({"SourceMissing", O::kExit, 3, "cannot open source",
               [](Env& e) { e.source = "replay:" + (e.root / "no_such_folder").string(); }});
  c.push_back({"SourceEmptyFolder", O::kExit, 3, "no files", [](Env& e) {
                 for (const auto& n : kGood) fs::remove(e.in / n);
               }});
  c.push_back({"SourceCorruptVideo", O::kExit, 3, "cannot open video", [](Env& e) {
                 Bytes b(20000);
                 Scramble(&b, 0, b.size(), 5);
                 WriteBytes(e.root / "flight.mp4", b);
                 e.source = "replay:" + (e.root / "flight.mp4").string();
               }});
  c.push_back({"SourceUnknownScheme", O::kExit, 2, "unknown source", [](Env& e) { e.source = "camera:/dev/video9"; }});
  c.push_back({"SourceDisappearsMidRun", O::kExit, 3, "replay folder disappeared", [](Env& e) {
                 // A longer flight, so that most of it is still unread when the folder goes.
                 for (const auto& entry : fs::directory_iterator(kImages))
                   fs::copy_file(entry.path(), e.in / entry.path().filename(), fs::copy_options::overwrite_existing);
                 e.remove_source_mid_run = true;
               }});
  return c;
}

// ---- running the program --------------------------------------------------------------------------------------

struct RunResult {
  bool exited = false;
  int exit_code = -1;
  int signal = 0;
  bool timed_out = false;
  std::string log;
};

size_t CountFiles(const fs::path& dir) {
  std::error_code ec;
  size_t n = 0;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) ++n;
  return n;
}

RunResult RunOnboard(const Env& env) {
  std::vector<std::string> args = {UAVM_ONBOARD_BIN, "--source", env.source, "--out", env.out.string()};
  const bool sets_work = std::find(env.args.begin(), env.args.end(), "--work-size") != env.args.end() ||
                         std::find(env.args.begin(), env.args.end(), "--max-features") != env.args.end();
  if (!sets_work) {
    for (const auto& a : test::EmulationArgs()) args.push_back(a);
  }
  args.insert(args.end(), env.args.begin(), env.args.end());
  const fs::path log = env.root / "log.txt";
  const pid_t pid = ::fork();
  if (pid == 0) {
    const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    ::dup2(fd, 1);
    ::dup2(fd, 2);
    if (env.fsize_limit > 0) {
      // A full disk: writes beyond the limit fail with EFBIG instead of killing the program with SIGXFSZ.
      ::signal(SIGXFSZ, SIG_IGN);
      const rlimit limit{env.fsize_limit, env.fsize_limit};
      ::setrlimit(RLIMIT_FSIZE, &limit);
    }
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  RunResult r;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(300);
  bool removed = false;
  int status = 0;
  for (;;) {
    const pid_t w = ::waitpid(pid, &status, WNOHANG);
    if (w == pid) break;
    if (std::chrono::steady_clock::now() > deadline) {
      ::kill(pid, SIGKILL);
      ::waitpid(pid, &status, 0);
      r.timed_out = true;
      break;
    }
    if (env.remove_source_mid_run && !removed && CountFiles(env.out / "frames") >= 2) {
      fs::remove_all(env.in);
      removed = true;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  r.exited = WIFEXITED(status);
  r.exit_code = r.exited ? WEXITSTATUS(status) : -1;
  r.signal = WIFSIGNALED(status) ? WTERMSIG(status) : 0;
  std::ifstream in(log);
  r.log.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  return r;
}

// Whatever the run left in the session directory is whole: the CSVs and the report parse, no temp file is left.
void ExpectNothingCorrupted(const fs::path& out) {
  std::error_code ec;
  if (!fs::is_directory(out, ec)) return;
  std::string text;
  std::string err;
  if (fs::exists(out / "transforms.csv")) {
    ASSERT_TRUE(ReadTextFile((out / "transforms.csv").string(), &text, &err));
    std::vector<TransformRow> rows;
    EXPECT_TRUE(ParseTransformsCsv(text, &rows, &err)) << "transforms.csv: " << err;
  }
  if (fs::exists(out / "report.json")) {
    ASSERT_TRUE(ReadTextFile((out / "report.json").string(), &text, &err));
    EXPECT_TRUE(nlohmann::json::accept(text)) << "report.json does not parse";
  }
  for (const char* csv : {"frames.csv", "graph.csv", "correspondences.csv"}) {
    if (!fs::exists(out / csv)) continue;
    ASSERT_TRUE(ReadTextFile((out / csv).string(), &text, &err));
    EXPECT_TRUE(!text.empty() && text.back() == '\n') << csv << " ends mid-line";
  }
  for (const char* image : {"mosaic.png", "live.jpg"}) {
    if (fs::exists(out / image)) {
      EXPECT_FALSE(cv::imread((out / image).string()).empty()) << image;
    }
  }
  for (const auto& e : fs::recursive_directory_iterator(out, ec))
    EXPECT_NE(e.path().extension(), ".tmp") << "left behind: " << e.path();
}

nlohmann::json Report(const fs::path& out) {
  std::ifstream in(out / "report.json");
  if (!in) return {};
  return nlohmann::json::parse(in, nullptr, false);
}

// gtest prints the parameter of a failing instance: its name is enough.
void PrintTo(const Case& c, std::ostream* os) {
  *os << c.name;
}

class BadInputTest : public ::testing::TestWithParam<Case> {};

TEST_P(BadInputTest, DocumentedOutcome) {
  const Case& c = GetParam();
  Env env;
  env.root = fs::temp_directory_path() / ("uavm_bad_" + c.name + "_" + std::to_string(::getpid()));
  fs::remove_all(env.root);
  env.in = env.root / "images";
  env.out = env.root / "session";
  fs::create_directories(env.in);
  CopyGood(env, kGood);
  env.source = "replay:" + env.in.string();
  env.args = {"--no-tiff", "--log-level", "info"};
  c.setup(env);
  if (HasFatalFailure()) return;

  const RunResult r = RunOnboard(env);
  SCOPED_TRACE("program log:\n" + r.log.substr(r.log.size() > 6000 ? r.log.size() - 6000 : 0));
  ASSERT_FALSE(r.timed_out) << "the program hung";
  ASSERT_TRUE(r.exited) << "the program died of signal " << r.signal;
  ExpectNothingCorrupted(env.out);

  const auto report = Report(env.out);
  const auto listed = [&](const char* key) -> nlohmann::json {
    if (!report.is_object() || !report.contains(key)) return {};
    for (const auto& s : report[key])
      if (s.value("file", "") == env.bad) return s;
    return {};
  };
  switch (c.outcome) {
    case Outcome::kSkipped: {
      ASSERT_EQ(r.exit_code, 0);
      EXPECT_EQ(report.value("registered", -1), env.good);
      const auto s = listed("skipped");
      ASSERT_TRUE(s.is_object()) << env.bad << " is not in report.json's skipped list";
      const std::string reason = s.value("reason", "");
      EXPECT_FALSE(reason.empty());
      EXPECT_NE(reason.find(c.message), std::string::npos) << "reason: " << reason;
      EXPECT_NE(r.log.find(env.bad), std::string::npos) << "the log does not name the bad input";
      break;
    }
    case Outcome::kUsable: {
      ASSERT_EQ(r.exit_code, 0);
      EXPECT_EQ(report.value("registered", -1), env.good + 1);
      EXPECT_FALSE(listed("skipped").is_object());
      EXPECT_FALSE(listed("unregistered").is_object());
      break;
    }
    case Outcome::kUnregistered: {
      ASSERT_EQ(r.exit_code, 0);
      EXPECT_EQ(report.value("registered", -1), env.good);
      EXPECT_FALSE(listed("skipped").is_object());
      const auto u = listed("unregistered");
      ASSERT_TRUE(u.is_object()) << env.bad << " is not in report.json's unregistered list";
      EXPECT_FALSE(u.value("reason", "").empty());
      break;
    }
    case Outcome::kExit: {
      EXPECT_EQ(r.exit_code, c.exit_code);
      EXPECT_NE(r.log.find(c.message), std::string::npos) << "expected message: " << c.message;
      if (c.exit_code == 0) {
        EXPECT_EQ(report.value("registered", -1), env.good);
      }
      if (env.remove_source_mid_run) {
        // A source lost mid-run: what was received is still mosaicked and reported.
        EXPECT_GE(report.value("registered", -1), 2);
      }
      break;
    }
  }
  if (!HasFailure()) fs::remove_all(env.root);
}

INSTANTIATE_TEST_SUITE_P(Corpus, BadInputTest, ::testing::ValuesIn(Cases()),
                         [](const ::testing::TestParamInfo<Case>& info) { return info.param.name; });

// A disk that fills up mid-flight, for real: the session lives on a 2 MiB tmpfs (mounting needs root, as CI has) and a
// flight of 18 frames of ~280 kB cannot fit. The program must stop taking frames as soon as one cannot be stored, exit
// with 4 and a clear message, and leave a session whose journaled frames are all whole; on a disk with room again,
// --resume must finish the flight with every frame registered (nothing accepted was lost).
TEST(DiskFullTest, MidFlightStopsAtOnceAndResumeFinishesTheFlight) {
  Env env;
  env.root = fs::temp_directory_path() / ("uavm_diskfull_" + std::to_string(::getpid()));
  fs::remove_all(env.root);
  const fs::path small_disk = env.root / "small_disk";
  fs::create_directories(small_disk);
  env.in = env.root / "images";
  fs::create_directories(env.in);
  // Under emulation the first 12 frames: still more than the small disk holds (~3.4 MB of frames alone).
  const test::FlightForTest flight(kImages, 12, env.root / "flight");
  int flight_frames = 0;
  for (const auto& entry : fs::directory_iterator(flight.path())) {
    if (entry.path().extension() != ".JPG") continue;
    fs::copy_file(fs::canonical(entry.path()), env.in / entry.path().filename());
    ++flight_frames;
  }
  ASSERT_EQ(flight_frames, flight.frames());
  if (::mount("tmpfs", small_disk.c_str(), "tmpfs", 0, "size=2m") != 0) {
    const std::string why = std::strerror(errno);
    fs::remove_all(env.root);
    GTEST_SKIP() << "cannot mount a 2 MiB tmpfs (" << why << "): this test needs root or CAP_SYS_ADMIN";
  }
  struct Unmount {
    fs::path dir;
    bool mounted = true;
    void operator()() {
      if (mounted) ::umount2(dir.c_str(), MNT_DETACH);
      mounted = false;
    }
    ~Unmount() { (*this)(); }
  } unmount{small_disk};

  env.out = small_disk / "session";
  env.source = "replay:" + env.in.string();
  env.args = {"--no-tiff", "--log-level", "info"};
  const RunResult full = RunOnboard(env);
  SCOPED_TRACE("program log (disk full):\n" + full.log.substr(full.log.size() > 6000 ? full.log.size() - 6000 : 0));
  ASSERT_FALSE(full.timed_out);
  ASSERT_TRUE(full.exited) << "died of signal " << full.signal;
  EXPECT_EQ(full.exit_code, 4);
  EXPECT_NE(full.log.find("cannot store frames any more"), std::string::npos);
  ExpectNothingCorrupted(env.out);

  // What was accepted before the disk filled is whole: every journaled frame decodes from the session.
  JournalContents journal;
  std::string error;
  ASSERT_TRUE(ReadJournal((env.out / "journal.jsonl").string(), &journal, &error)) << error;
  EXPECT_GE(journal.frames.size(), 2u);
  EXPECT_LT(journal.frames.size(), static_cast<size_t>(flight_frames)) << "the flight fitted: the disk is too big";
  for (const auto& f : journal.frames)
    EXPECT_FALSE(cv::imread((env.out / "frames" / f.stored_file).string()).empty()) << f.stored_file;
  // Stopped at once: frames are not taken (and lost) after the first one that failed. Frames already prepared in the
  // capture queue (2) may be counted as received.
  const size_t stored_files = CountFiles(env.out / "frames");
  EXPECT_LE(stored_files, journal.frames.size() + 1);

  // Room again (the session moved to a bigger disk): --resume finishes the flight.
  const fs::path roomy = env.root / "session";
  fs::copy(env.out, roomy, fs::copy_options::recursive);
  unmount();
  env.out = roomy;
  env.args.push_back("--resume");
  const RunResult resumed = RunOnboard(env);
  SCOPED_TRACE("program log (resumed):\n" +
               resumed.log.substr(resumed.log.size() > 6000 ? resumed.log.size() - 6000 : 0));
  ASSERT_TRUE(resumed.exited);
  EXPECT_EQ(resumed.exit_code, 0);
  ExpectNothingCorrupted(env.out);
  const auto report = Report(env.out);
  EXPECT_EQ(report.value("resumed_frames", -1), static_cast<int>(journal.frames.size()));
  EXPECT_EQ(report.value("frames_decoded", -1), flight_frames);
  EXPECT_EQ(report.value("registered", -1), flight_frames);
  if (!HasFailure()) fs::remove_all(env.root);
}

}  // namespace
}  // namespace uavm
