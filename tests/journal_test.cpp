#include "core/session/journal.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "core/session/session_dir.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;

fs::path TempFile(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("uavm_journal_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  return dir / name;
}

TEST(JournalTest, RoundTripAndAppendAfterResume) {
  const fs::path path = TempFile("a.jsonl");
  std::string err;
  {
    SessionJournal j;
    ASSERT_TRUE(j.Open(path.string(), false, 0, 2, &err)) << err;
    ASSERT_TRUE(j.AddFrame({0, "DJI_0001.JPG", "000000_DJI_0001.JPG", 10, 4000, 3000}, &err));
    ASSERT_TRUE(j.AddSkip({"broken.jpg", "cannot decode"}, &err));
    ASSERT_TRUE(j.AddFrame({1, "DJI_0002.JPG", "000001_DJI_0002.JPG", 20, 4000, 3000}, &err));
    EXPECT_GE(j.syncs(), 2u);  // the header, then every second frame
  }
  JournalContents c;
  ASSERT_TRUE(ReadJournal(path.string(), &c, &err)) << err;
  ASSERT_EQ(c.frames.size(), 2u);
  EXPECT_EQ(c.frames[1].name, "DJI_0002.JPG");
  EXPECT_EQ(c.frames[1].stored_file, "000001_DJI_0002.JPG");
  EXPECT_EQ(c.frames[1].timestamp_ns, 20);
  EXPECT_FALSE(c.frames[1].latitude_deg.has_value());
  ASSERT_EQ(c.skipped.size(), 1u);
  EXPECT_EQ(c.skipped[0].reason, "cannot decode");
  EXPECT_FALSE(c.finished);
  EXPECT_EQ(c.torn_lines, 0);
  EXPECT_EQ(c.valid_bytes, fs::file_size(path));
  {
    SessionJournal j;
    ASSERT_TRUE(j.Open(path.string(), true, c.valid_bytes, 1, &err)) << err;
    ASSERT_TRUE(j.AddFrame({2, "DJI_0003.JPG", "000002_DJI_0003.JPG", 30, 4000, 3000}, &err));
    ASSERT_TRUE(j.AddFinished(&err));
  }
  ASSERT_TRUE(ReadJournal(path.string(), &c, &err)) << err;
  EXPECT_EQ(c.frames.size(), 3u);
  EXPECT_TRUE(c.finished);
}

TEST(JournalTest, TornLastLineIsDroppedAndCutOffBeforeAppending) {
  const fs::path path = TempFile("torn.jsonl");
  std::string err;
  {
    SessionJournal j;
    ASSERT_TRUE(j.Open(path.string(), false, 0, 1, &err)) << err;
    ASSERT_TRUE(j.AddFrame({0, "a.jpg", "000000_a.jpg", 1, 640, 480}, &err));
  }
  const auto whole = fs::file_size(path);
  {
    std::ofstream out(path, std::ios::app | std::ios::binary);
    out << R"({"type":"frame","id":1,"name":"b.jp)";  // killed mid-write
  }
  JournalContents c;
  ASSERT_TRUE(ReadJournal(path.string(), &c, &err)) << err;
  EXPECT_EQ(c.frames.size(), 1u);
  EXPECT_EQ(c.torn_lines, 1);
  EXPECT_EQ(c.valid_bytes, whole);
  {
    SessionJournal j;
    ASSERT_TRUE(j.Open(path.string(), true, c.valid_bytes, 1, &err)) << err;
    ASSERT_TRUE(j.AddFrame({1, "b.jpg", "000001_b.jpg", 2, 640, 480}, &err));
  }
  ASSERT_TRUE(ReadJournal(path.string(), &c, &err)) << err;
  EXPECT_EQ(c.frames.size(), 2u);
  EXPECT_EQ(c.torn_lines, 0);
}

TEST(JournalTest, RefusesWhatIsNotAJournal) {
  JournalContents c;
  std::string err;
  EXPECT_FALSE(ParseJournal("hello\n", &c, &err));
  EXPECT_FALSE(ParseJournal(R"({"type":"session","version":99})"
                            "\n",
                            &c, &err));
  // Frames out of order end the journal there (a later line cannot be trusted).
  ASSERT_TRUE(
      ParseJournal(R"({"type":"session","version":1})"
                   "\n"
                   R"({"type":"frame","id":1,"name":"x","stored":"000001_x","timestamp_ns":0,"width":2,"height":2})"
                   "\n",
                   &c, &err));
  EXPECT_TRUE(c.frames.empty());
  EXPECT_EQ(c.torn_lines, 1);
  // A path in the stored name would point outside frames/.
  ASSERT_TRUE(ParseJournal(
      R"({"type":"session","version":1})"
      "\n"
      R"({"type":"frame","id":0,"name":"x","stored":"../../etc/passwd","timestamp_ns":0,"width":2,"height":2})"
      "\n",
      &c, &err));
  EXPECT_TRUE(c.frames.empty());
  // A missing journal is an empty one (a run killed before its first line).
  EXPECT_TRUE(ReadJournal("/nonexistent_uavm/journal.jsonl", &c, &err));
  EXPECT_TRUE(c.frames.empty());
}

// A frame's position (telemetry's, which its stored file does not carry) comes back on resume; a value that is not
// a number is left out, the rest of the line kept.
TEST(JournalTest, FramePositionsRoundTrip) {
  const fs::path path = TempFile("pose.jsonl");
  std::string err;
  {
    SessionJournal j;
    ASSERT_TRUE(j.Open(path.string(), false, 0, 1, &err)) << err;
    JournalFrame f{0, "a.png", "000000_a.png", 10, 400, 300};
    f.latitude_deg = 46.8426123456789;
    f.longitude_deg = -91.9946987654321;
    f.relative_altitude_m = 80.25;
    f.yaw_deg = 271.5;
    ASSERT_TRUE(j.AddFrame(f, &err)) << err;
    ASSERT_TRUE(j.AddFrame({1, "b.png", "000001_b.png", 20, 400, 300}, &err)) << err;
  }
  JournalContents c;
  ASSERT_TRUE(ReadJournal(path.string(), &c, &err)) << err;
  ASSERT_EQ(c.frames.size(), 2u);
  EXPECT_DOUBLE_EQ(*c.frames[0].latitude_deg, 46.8426123456789);
  EXPECT_DOUBLE_EQ(*c.frames[0].longitude_deg, -91.9946987654321);
  EXPECT_DOUBLE_EQ(*c.frames[0].relative_altitude_m, 80.25);
  EXPECT_DOUBLE_EQ(*c.frames[0].yaw_deg, 271.5);
  EXPECT_FALSE(c.frames[1].latitude_deg.has_value());
  std::string text;
  ASSERT_TRUE(ReadTextFile(path.string(), &text, &err));
  const size_t at = text.find("\"lat\":");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, 6, "\"lat\":\"north\",\"x\":");
  ASSERT_TRUE(ParseJournal(text, &c, &err)) << err;
  ASSERT_EQ(c.frames.size(), 2u);
  EXPECT_FALSE(c.frames[0].latitude_deg.has_value());
  EXPECT_DOUBLE_EQ(*c.frames[0].longitude_deg, -91.9946987654321);
}

}  // namespace
}  // namespace uavm
