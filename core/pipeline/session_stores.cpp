#include "core/pipeline/session_stores.h"

#include <spdlog/spdlog.h>

#include <filesystem>
#include <opencv2/imgcodecs.hpp>

#include "core/radiometry/radiometry.h"
#include "core/util/memory.h"

namespace uavm {

namespace fs = std::filesystem;

std::string StoredName(int id, const std::string& name) {
  char prefix[16];
  std::snprintf(prefix, sizeof(prefix), "%06d_", id);
  std::string safe = name;
  for (char& c : safe)
    if (c == '/' || c == ':' || c == '\\') c = '_';
  return prefix + safe;
}

// The engine's view of the feature cache.
class SessionStores::FeatureView final : public FeatureProvider {
 public:
  explicit FeatureView(FeatureStore* store) : store_(store) {}
  std::shared_ptr<const Features> Get(int id) override { return store_->Get(id); }
  std::shared_ptr<const Features> Load(int id) override {
    auto features = std::make_shared<Features>();
    std::string err;
    if (!store_->Load(id, features.get(), &err)) {
      spdlog::warn("features of frame {}: {}", id, err);
      return nullptr;
    }
    return features;
  }
  void ReleaseAll() override {
    store_->Clear();
    TrimHeap();  // the solves and the compositor get the pages back
  }

 private:
  FeatureStore* store_;  // borrowed: the SessionStores'
};

// The engine's view of edges.bin.
class SessionStores::EdgeView final : public EdgeSpill {
 public:
  explicit EdgeView(EdgeStore* store) : store_(store) {}
  bool Append(Edge* edge, std::string* error) override { return store_->Append(edge, error); }
  bool Load(Edge* edge, std::string* error) override { return store_->Load(edge, error); }
  size_t Release(Edge* edge) override { return store_->Release(edge); }

 private:
  EdgeStore* store_;  // borrowed: the SessionStores'
};

SessionStores::SessionStores(const SessionPaths& paths, size_t feature_cache_bytes)
    : thumbs_dir_(paths.Join("thumbs")),
      feature_store_(paths.features(), feature_cache_bytes),
      feature_view_(std::make_unique<FeatureView>(&feature_store_)) {
  std::string error;
  if (edge_store_.Open(paths.Join("edges.bin"), &error))
    edge_view_ = std::make_unique<EdgeView>(&edge_store_);
  else
    spdlog::warn("{}; edge points stay in memory", error);
}

SessionStores::~SessionStores() = default;

FeatureProvider* SessionStores::feature_provider() {
  return feature_view_.get();
}

EdgeSpill* SessionStores::edge_spill() {
  return edge_view_.get();
}

bool SessionStores::StoreFrameBytes(const Frame& frame, const std::vector<uchar>& encoded,
                                    const std::string& stored_file, std::string* error) const {
  std::error_code ec;
  if (!frame.source_path.empty()) {
    // The original bytes, EXIF included: the ground tool and the final composite read them at full resolution.
    fs::copy_file(frame.source_path, stored_file, fs::copy_options::overwrite_existing, ec);
    if (ec) {
      *error = "cannot store frame " + frame.source_name + ": " + ec.message();
      return false;
    }
    return true;
  }
  if (encoded.empty() || !WriteFileAtomic(stored_file, std::string(encoded.begin(), encoded.end()), error)) {
    *error = "cannot store frame " + frame.source_name + (error->empty() ? "" : ": " + *error);
    return false;
  }
  return true;
}

std::string SessionStores::ThumbPath(const std::string& thumbs_dir, int id) {
  return thumbs_dir + "/" + std::to_string(id) + ".png";
}

cv::Mat SessionStores::StoreThumbnail(int id, const cv::Mat& work_bgr, int thumb_long_side) {
  if (work_bgr.empty()) return {};
  if (!thumbs_dir_made_) {
    std::error_code ec;
    thumbs_dir_made_ = fs::create_directories(thumbs_dir_, ec) || fs::is_directory(thumbs_dir_, ec);
  }
  cv::Mat thumb = MakeThumbnail(work_bgr, thumb_long_side);
  try {
    if (!cv::imwrite(ThumbPath(thumbs_dir_, id), thumb))
      spdlog::warn("radiometry: cannot write the thumbnail of frame {}", id);
  } catch (const cv::Exception& e) {
    spdlog::warn("radiometry: cannot write the thumbnail of frame {}: {}", id, e.what());
  }
  return thumb;
}

}  // namespace uavm
