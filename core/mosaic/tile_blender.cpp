#include "core/mosaic/tile_blender.h"

#include <opencv2/stitching/detail/blenders.hpp>

namespace uavm {

namespace {

class MultiBand final : public TileBlender {
 public:
  explicit MultiBand(int bands) : bands_(bands) {}
  void Prepare(const cv::Rect& roi) override {
    blender_ = std::make_unique<cv::detail::MultiBandBlender>(false, bands_, CV_32F);
    blender_->prepare(roi);
  }
  void Feed(const cv::Mat& image, const cv::Mat& mask, cv::Point top_left) override {
    cv::Mat s16;
    image.convertTo(s16, CV_16SC3);
    blender_->feed(s16, mask, top_left);
  }
  void Blend(cv::Mat* image, cv::Mat* mask) override {
    cv::Mat result;
    blender_->blend(result, *mask);
    result.convertTo(*image, CV_8UC3);
  }

 private:
  int bands_;
  std::unique_ptr<cv::detail::MultiBandBlender> blender_;
};

class SeamOnly final : public TileBlender {
 public:
  void Prepare(const cv::Rect& roi) override {
    roi_ = roi;
    image_.create(roi.size(), CV_8UC3);
    image_.setTo(cv::Scalar::all(0));
    mask_.create(roi.size(), CV_8U);
    mask_.setTo(0);
  }
  void Feed(const cv::Mat& image, const cv::Mat& mask, cv::Point top_left) override {
    const cv::Rect r(top_left - roi_.tl(), image.size());
    image.copyTo(image_(r), mask);
    mask_(r).setTo(255, mask);
  }
  void Blend(cv::Mat* image, cv::Mat* mask) override {
    *image = image_;
    *mask = mask_;
  }

 private:
  cv::Rect roi_;
  cv::Mat image_;
  cv::Mat mask_;
};

}  // namespace

std::unique_ptr<TileBlender> MakeMultiBandBlender(int num_bands) {
  return std::make_unique<MultiBand>(num_bands);
}
std::unique_ptr<TileBlender> MakeSeamOnlyBlender() {
  return std::make_unique<SeamOnly>();
}

}  // namespace uavm
