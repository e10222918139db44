#include "hal/replay/replay_source.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "hal/replay/natural_order.h"

namespace uavm::hal {
namespace {

namespace fs = std::filesystem;
const std::string kFlight = std::string(UAVM_TEST_DATA) + "/brighton_beach_small/images";

TEST(NaturalOrderTest, NumbersCompareAsNumbers) {
  std::vector<std::string> v{"img10.jpg", "img2.jpg", "img1.jpg", "IMG_0100.jpg", "IMG_0099.jpg"};
  std::sort(v.begin(), v.end(), NaturalLess);
  EXPECT_EQ(v, (std::vector<std::string>{"IMG_0099.jpg", "IMG_0100.jpg", "img1.jpg", "img2.jpg", "img10.jpg"}));
}

TEST(ReplaySourceTest, ReadsAFolderInOrderWithReducedDecoding) {
  ReplaySource src({kFlight, 1, true});
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  src.SetDecodeHint({400});  // 1000 px frames: a 1/2 decode (500 px) still covers 400 px
  Frame f;
  ASSERT_EQ(src.Next(&f, &err), Status::kOk) << err;
  EXPECT_EQ(f.source_name, "DJI_0018.JPG");
  EXPECT_EQ(f.original_size, cv::Size(1000, 562));
  EXPECT_EQ(f.image.cols, 500);
  EXPECT_DOUBLE_EQ(f.decode_scale, 0.5);
  EXPECT_TRUE(f.metadata.HasGps());
  int64_t last_ts = f.timestamp_ns;
  int count = 1;
  while (src.Next(&f, &err) == Status::kOk) {
    EXPECT_GT(f.timestamp_ns, last_ts);
    last_ts = f.timestamp_ns;
    ++count;
  }
  EXPECT_EQ(count, 18);
}

TEST(ReplaySourceTest, BadFilesAreSkippedWithAReason) {
  const fs::path dir = fs::temp_directory_path() / ("uavm_replay_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  fs::copy_file(kFlight + "/DJI_0018.JPG", dir / "a_01.jpg");
  std::ofstream(dir / "a_02.jpg").close();                    // zero bytes
  std::ofstream(dir / "a_03.jpg") << "this is not an image";  // garbage
  {
    std::ifstream in(kFlight + "/DJI_0019.JPG", std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    std::ofstream(dir / "a_04.jpg", std::ios::binary) << bytes.substr(0, bytes.size() / 2);  // truncated
  }
  ReplaySource src({dir.string(), 1, false});
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk);
  Frame f;
  EXPECT_EQ(src.Next(&f, &err), Status::kOk);
  EXPECT_EQ(src.Next(&f, &err), Status::kSkipped);
  EXPECT_NE(err.find("0 bytes"), std::string::npos) << err;
  EXPECT_EQ(src.Next(&f, &err), Status::kSkipped);
  EXPECT_EQ(f.source_name, "a_03.jpg");
  EXPECT_EQ(src.Next(&f, &err), Status::kSkipped);
  EXPECT_NE(err.find("truncated"), std::string::npos) << err;
  EXPECT_EQ(src.Next(&f, &err), Status::kEndOfStream);
  fs::remove_all(dir);
}

TEST(ReplaySourceTest, VideoWithStride) {
  const fs::path video = fs::temp_directory_path() / ("uavm_replay_" + std::to_string(::getpid()) + ".avi");
  {
    cv::VideoWriter writer(video.string(), cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 10.0, cv::Size(500, 282));
    ASSERT_TRUE(writer.isOpened());
    for (const char* name : {"DJI_0018.JPG", "DJI_0019.JPG", "DJI_0020.JPG", "DJI_0021.JPG", "DJI_0022.JPG"}) {
      cv::Mat img = cv::imread(kFlight + "/" + name);
      cv::resize(img, img, cv::Size(500, 282));
      writer.write(img);
    }
  }
  ReplaySource src({video.string(), 2, true});
  std::string err;
  ASSERT_EQ(src.Open(&err), Status::kOk) << err;
  std::vector<std::string> names;
  Frame f;
  while (src.Next(&f, &err) == Status::kOk) {
    EXPECT_EQ(f.original_size, cv::Size(500, 282));
    names.push_back(f.source_name);
  }
  EXPECT_EQ(names, (std::vector<std::string>{"video:0", "video:2", "video:4"}));  // stride 2 of 5 frames
  fs::remove(video);
}

// The video module is found where UAVM_VIDEO_READER says, and a missing one is a clear error, not a crash; the
// program itself never maps videoio (hal/replay/video_reader.h).
TEST(ReplaySourceTest, VideoModuleMissingIsASourceErrorNamingIt) {
  const fs::path video = fs::temp_directory_path() / ("uavm_replay_module_" + std::to_string(::getpid()) + ".avi");
  {
    cv::VideoWriter writer(video.string(), cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 10.0, cv::Size(320, 240));
    ASSERT_TRUE(writer.isOpened());
    for (int i = 0; i < 2; ++i) writer.write(cv::Mat(240, 320, CV_8UC3, cv::Scalar::all(40 * i)));
  }
  ASSERT_EQ(::setenv("UAVM_VIDEO_READER", "/nonexistent/libuavm_video_reader.so", 1), 0);
  std::string error;
  {
    ReplaySource src({video.string(), 1, true});
    EXPECT_EQ(src.Open(&error), Status::kError);
  }
  ::unsetenv("UAVM_VIDEO_READER");
  EXPECT_NE(error.find("libuavm_video_reader.so"), std::string::npos) << error;
  EXPECT_NE(error.find("/nonexistent/"), std::string::npos) << error;
  // Found again without the variable (the build tree's module), and it reads the frames.
  ReplaySource src({video.string(), 1, true});
  ASSERT_EQ(src.Open(&error), Status::kOk) << error;
  Frame frame;
  int frames = 0;
  while (src.Next(&frame, &error) == Status::kOk) ++frames;
  EXPECT_EQ(frames, 2);
  src.Close();
  fs::remove(video);
}

TEST(ReplaySourceTest, MissingFolderIsASourceError) {
  ReplaySource src({"/nonexistent/uavm/flight", 1, true});
  std::string err;
  EXPECT_EQ(src.Open(&err), Status::kError);
  EXPECT_NE(err.find("/nonexistent/uavm/flight"), std::string::npos);
}

}  // namespace
}  // namespace uavm::hal
