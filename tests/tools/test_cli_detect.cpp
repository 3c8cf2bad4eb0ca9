// `stereoloc detect`: JSON keys, overlay, and one-line errors for bad input.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <utility>
#include <vector>
#include <opencv2/imgproc.hpp>

#include "cli_util.h"
#include "src/io/image_file.h"

namespace stereoloc {
namespace {

namespace fs = std::filesystem;

struct TempDir {
  fs::path path;
  TempDir() {
    path = fs::temp_directory_path() / ("stereoloc_detect_" + std::to_string(::getpid()));
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
  std::string file(const std::string& name) const { return (path / name).string(); }
};

// A pair with a yellow goal between white walls (shifted by 8 px in the right image) and a
// white marking on the dark floor.
void writePair(const TempDir& d) {
  for (int cam = 0; cam < 2; ++cam) {
    cv::Mat img(240, 320, CV_8UC3, cv::Scalar(20, 20, 20));
    const int shift = cam ? -8 : 0;
    cv::rectangle(img, cv::Rect(0, 100, 320, 20), cv::Scalar(235, 235, 235), cv::FILLED);
    cv::rectangle(img, cv::Rect(130 + shift, 100, 60, 20), cv::Scalar(40, 225, 245), cv::FILLED);
    cv::line(img, cv::Point(60 + shift, 239), cv::Point(150 + shift, 125), cv::Scalar(230, 230, 230), 3, cv::LINE_AA);
    writePngFile(d.file(cam ? "right.png" : "left.png"), img);
  }
}

}  // namespace

TEST(CliDetect, JsonHasTheDocumentedKeys) {
  TempDir d;
  writePair(d);
  const test::CliRun r = test::runCli("detect --left " + d.file("left.png") + " --right " + d.file("right.png") +
                                      " --json --overlay " + d.file("overlay.png"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* key : {"\"segments\"", "\"features\"", "\"observations\"", "\"x1\"", "\"marking\"", "\"type\"",
                          "\"goal_corner\"", "\"landmark_id\"", "\"range\"", "\"bearing\"", "\"u_left\"", "\"u_right\""})
    EXPECT_NE(r.output.find(key), std::string::npos) << key << "\n" << r.output;
  EXPECT_EQ(r.output.front(), '{');
  EXPECT_TRUE(fs::exists(d.file("overlay.png")));
  // The table form prints the same observations.
  const test::CliRun t = test::runCli("detect --left " + d.file("left.png") + " --right " + d.file("right.png"));
  ASSERT_EQ(t.exit_code, 0) << t.output;
  EXPECT_NE(t.output.find("goal_corner"), std::string::npos) << t.output;
}

TEST(CliDetect, BadInputGivesAOneLineErrorAndExit1) {
  TempDir d;
  writePair(d);
  writePngFile(d.file("small.png"), cv::Mat(120, 160, CV_8UC3, cv::Scalar(10, 10, 10)));
  writePngFile(d.file("grey.png"), cv::Mat(240, 320, CV_8UC1, cv::Scalar(10)));
  writePngFile(d.file("deep.png"), cv::Mat(240, 320, CV_16UC3, cv::Scalar(1000, 1000, 1000)));
  {
    std::FILE* f = std::fopen(d.file("empty.png").c_str(), "w");
    std::fclose(f);
  }
  {
    std::ifstream in(d.file("right.png"), std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    std::ofstream(d.file("cut.png"), std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  }
  std::ofstream(d.file("bitmap.bmp"), std::ios::binary) << "BM a bitmap header and pixels";
  const std::string L = " --left " + d.file("left.png"), R = " --right " + d.file("right.png");
  // Each case with the file and the words its message must hold.
  const std::vector<std::pair<std::string, std::vector<std::string>>> cases = {
      {"detect" + L + " --right " + d.file("small.png"), {d.file("small.png"), "right image", "160x120", "320x240"}},
      {"detect --left " + d.file("small.png") + " --right " + d.file("small.png"), {d.file("small.png"), "left image"}},
      {"detect" + L + " --right " + d.file("grey.png"), {d.file("grey.png"), "1 channel"}},
      {"detect" + L + " --right " + d.file("deep.png"), {d.file("deep.png"), "16-bit"}},
      {"detect" + L + " --right " + d.file("empty.png"), {d.file("empty.png"), "empty file"}},
      {"detect" + L + " --right " + d.file("cut.png"), {d.file("cut.png"), "PNG cut short"}},
      {"detect" + L + " --right " + d.file("missing.png"), {d.file("missing.png"), "no such file"}},
      {"detect" + L + " --right " + d.file("bitmap.bmp"), {d.file("bitmap.bmp"), "not a PNG or JPEG image"}},
      {"detect" + L + R + " --overlay " + d.file("overlay.jpg"), {d.file("overlay.jpg"), "give a .png path"}}};
  for (const auto& [args, words] : cases) {
    const test::CliRun r = test::runCli(args);
    EXPECT_EQ(r.exit_code, 1) << args << "\n" << r.output;
    EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << args << "\n" << r.output;
    for (const std::string& w : words) EXPECT_NE(r.output.find(w), std::string::npos) << w << "\n" << r.output;
  }
  EXPECT_EQ(test::runCli("detect" + L).exit_code, 2);  // --right missing: usage error
}

TEST(CliDetect, OneImageGivesSegmentsCornersAndAnOverlayWithoutObservations) {
  TempDir d;
  const std::string real = std::string(STEREOLOC_DATA_DIR) + "/real";
  const std::string args = "detect --image " + real + "/images/20190606_r2_cam0_20190606_204349.jpg --rig " + real +
                           "/rig.yaml --params " + real + "/frontend.yaml --json --overlay " + d.file("overlay.png");
  const test::CliRun r = test::runCli(args);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("\"marking\": true"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("\"observations\": []"), std::string::npos) << r.output;
  const cv::Mat ov = readImageFile(d.file("overlay.png"), ImageColour::Bgr).image;
  ASSERT_FALSE(ov.empty());
  EXPECT_EQ(ov.cols, 640);  // drawn at twice the input size
  EXPECT_EQ(ov.rows, 480);
}

TEST(CliDetect, OneImageBadInputGivesAOneLineError) {
  TempDir d;
  writePair(d);
  writePngFile(d.file("small.png"), cv::Mat(120, 160, CV_8UC3, cv::Scalar(10, 10, 10)));
  for (const std::string& args : {"detect --image " + d.file("small.png"), "detect --image " + d.file("missing.png")}) {
    const test::CliRun r = test::runCli(args);
    EXPECT_EQ(r.exit_code, 1) << args << "\n" << r.output;
    EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << args << "\n" << r.output;
  }
  // --image with a pair, or nothing at all: usage errors.
  EXPECT_EQ(test::runCli("detect --image " + d.file("left.png") + " --left " + d.file("left.png") + " --right " +
                         d.file("right.png")).exit_code, 2);
  EXPECT_EQ(test::runCli("detect").exit_code, 2);
  // A mono image of the rig's size runs with the built-in rig.
  EXPECT_EQ(test::runCli("detect --image " + d.file("left.png")).exit_code, 0);
}

}  // namespace stereoloc
