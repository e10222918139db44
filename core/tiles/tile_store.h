#pragma once
// The pyramid's tiles on disk (DIR/z/x/y.png, RGBA) behind a fixed-size cache of decoded tiles: what the live pyramid
// holds in memory is `capacity` x 256 KiB, however large the map. Single-threaded (the pyramid's worker owns it).
#include <cstdint>
#include <list>
#include <opencv2/core.hpp>
#include <string>
#include <unordered_map>

namespace uavm {

struct TileKey {
  int z = 0, x = 0, y = 0;
  bool operator==(const TileKey&) const = default;
};
struct TileKeyHash {
  size_t operator()(const TileKey& k) const {
    return std::hash<uint64_t>()((static_cast<uint64_t>(k.z) << 58) ^ (static_cast<uint64_t>(k.x) << 29) ^
                                 static_cast<uint64_t>(k.y));
  }
};

class TileStore {
 public:
  TileStore(std::string dir, int capacity, int png_compression);

  // The tile's pixels (CV_8UC4, colour 0 wherever alpha is 0), read from disk or transparent; cached. The reference
  // stays valid until the next Get().
  [[nodiscard]] cv::Mat& Get(const TileKey& key);
  // Marks a tile Get() returned as changed: written by Flush() (or when the cache evicts it).
  void MarkDirty(const TileKey& key);
  // Writes every changed tile (temp file + rename: a reader gets the old or the new tile, never half); a tile with
  // nothing in it is removed. Returns false on the first write error (message in `error`).
  [[nodiscard]] bool Flush(std::string* error);
  // Forgets every tile, in memory and on disk (a new grid).
  void Clear();

  [[nodiscard]] const std::string& dir() const { return dir_; }
  [[nodiscard]] std::string PathOf(const TileKey& key) const;
  [[nodiscard]] int64_t tiles_written() const { return written_; }
  [[nodiscard]] int64_t write_errors() const { return write_errors_; }

 private:
  struct Entry {
    cv::Mat pixels;
    bool dirty = false;
    std::list<TileKey>::iterator lru;
  };
  [[nodiscard]] bool Write(const TileKey& key, const cv::Mat& pixels, std::string* error);

  std::string dir_;
  size_t capacity_;
  int png_compression_;
  std::list<TileKey> lru_;  // most recently used first
  std::unordered_map<TileKey, Entry, TileKeyHash> entries_;
  int64_t written_ = 0;
  int64_t write_errors_ = 0;
};

}  // namespace uavm
