#include "core/tiles/tile_store.h"

#include <spdlog/spdlog.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <system_error>
#include <vector>

#include "core/tiles/tile_set.h"

namespace uavm {

namespace fs = std::filesystem;

TileStore::TileStore(std::string dir, int capacity, int png_compression)
    : dir_(std::move(dir)), capacity_(static_cast<size_t>(std::max(4, capacity))), png_compression_(png_compression) {}

std::string TileStore::PathOf(const TileKey& key) const {
  return dir_ + "/" + std::to_string(key.z) + "/" + std::to_string(key.x) + "/" + std::to_string(key.y) + ".png";
}

cv::Mat& TileStore::Get(const TileKey& key) {
  auto it = entries_.find(key);
  if (it != entries_.end()) {
    lru_.splice(lru_.begin(), lru_, it->second.lru);
    return it->second.pixels;
  }
  if (entries_.size() >= capacity_) {
    const TileKey victim = lru_.back();
    Entry& e = entries_.at(victim);
    std::string error;
    if (e.dirty && !Write(victim, e.pixels, &error)) spdlog::warn("live tiles: {}", error);
    lru_.pop_back();
    entries_.erase(victim);
  }
  const std::string path = PathOf(key);
  std::error_code ec;
  cv::Mat pixels = fs::exists(path, ec) ? cv::imread(path, cv::IMREAD_UNCHANGED) : cv::Mat();
  if (pixels.type() != CV_8UC4 || pixels.rows != kTileSize || pixels.cols != kTileSize)
    pixels = cv::Mat(kTileSize, kTileSize, CV_8UC4, cv::Scalar::all(0));
  lru_.push_front(key);
  Entry& e = entries_[key];
  e.pixels = std::move(pixels);
  e.lru = lru_.begin();
  return e.pixels;
}

void TileStore::MarkDirty(const TileKey& key) {
  auto it = entries_.find(key);
  if (it != entries_.end()) it->second.dirty = true;
}

bool TileStore::Flush(std::string* error) {
  for (auto& [key, e] : entries_) {
    if (!e.dirty) continue;
    if (!Write(key, e.pixels, error)) return false;
    e.dirty = false;
  }
  return true;
}

bool TileStore::Write(const TileKey& key, const cv::Mat& pixels, std::string* error) {
  const std::string path = PathOf(key);
  std::vector<cv::Mat> planes;
  cv::split(pixels, planes);
  if (cv::countNonZero(planes[3]) == 0) {  // nothing drawn: no file (a client gets 404, as for any empty tile)
    std::error_code ec;
    fs::remove(path, ec);
    return true;
  }
  std::vector<uchar> png;
  if (!cv::imencode(".png", pixels, png, {cv::IMWRITE_PNG_COMPRESSION, png_compression_})) {
    *error = "cannot encode " + path;
    ++write_errors_;
    return false;
  }
  std::error_code ec;
  fs::create_directories(fs::path(path).parent_path(), ec);
  const std::string tmp = path + ".part";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(png.data()), static_cast<std::streamsize>(png.size()));
    if (!out.flush()) {
      *error = "cannot write " + tmp + " (disk full?)";
      ++write_errors_;
      std::remove(tmp.c_str());
      return false;
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    *error = "cannot rename " + tmp;
    ++write_errors_;
    return false;
  }
  ++written_;
  return true;
}

void TileStore::Clear() {
  entries_.clear();
  lru_.clear();
  std::error_code ec;
  fs::remove_all(dir_, ec);
}

}  // namespace uavm
