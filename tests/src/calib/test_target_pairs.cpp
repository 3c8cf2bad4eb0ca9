// Finding checkerboard pairs on disk: folders named as stereoloc and as OpenCV's samples name
// them, OpenCV image lists, and the errors for what cannot be paired or read.
#include "src/calib/target_pairs.h"

#include <gtest/gtest.h>

#include <fstream>

#include "src/io/image_file.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// An image whose grey value tells it apart.
void writeImage(const std::string& path, int value) {
  ASSERT_NO_THROW(writePngFile(path, cv::Mat(12, 16, CV_8UC1, cv::Scalar(value))));
}

int valueOf(const cv::Mat& image) { return image.at<uint8_t>(0, 0); }

// The pair holds the images written with these values.
void expectPair(const TargetPair& pair, int left, int right) {
  EXPECT_EQ(valueOf(pair.left), left) << pair.name;
  EXPECT_EQ(valueOf(pair.right), right) << pair.name;
}

void writePair(const test::TempDir& dir, const std::string& left, const std::string& right, int value) {
  writeImage(dir.file(left), value);
  writeImage(dir.file(right), value + 1);
}

void writeText(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

TEST(TargetPairs, AFolderPairsLeftAndRightByTheirKey) {
  test::TempDir dir;
  writePair(dir, "left_b.png", "right_b.png", 10);
  writePair(dir, "left_a.png", "right_a.png", 20);
  writeText(dir.file("left_notes.txt"), "not an image");
  writeText(dir.file("README"), "");
  const std::vector<TargetPair> pairs = readTargetPairs(dir.path());
  ASSERT_EQ(pairs.size(), 2u);
  EXPECT_EQ(pairs[0].name, dir.file("left_a.png"));
  expectPair(pairs[0], 20, 21);
  expectPair(pairs[1], 10, 11);
  EXPECT_EQ(pairs[0].left.type(), CV_8UC1);
}

TEST(TargetPairs, OpenCvSampleNamesPairWithoutASeparator) {
  test::TempDir dir;
  writePair(dir, "left01.png", "right01.png", 1);
  writePair(dir, "Left-02.png", "RIGHT02.png", 3);
  const std::vector<TargetPair> pairs = readTargetPairs(dir.path());
  ASSERT_EQ(pairs.size(), 2u);
  expectPair(pairs[0], 1, 2);
  expectPair(pairs[1], 3, 4);
}

TEST(TargetPairs, AnImageListAlternatesLeftAndRightRelativeToItsFolder) {
  test::TempDir dir;
  std::filesystem::create_directories(dir.file("img"));
  writePair(dir, "img/l1.png", "img/r1.png", 5);
  writePair(dir, "img/l2.png", "img/r2.png", 7);
  writeText(dir.file("list.xml"),
            "<?xml version=\"1.0\"?>\n<opencv_storage>\n<imagelist>\n\"img/l2.png\"\n\"img/r2.png\"\n\"img/l1.png\"\n"
            "\"img/r1.png\"\n</imagelist>\n</opencv_storage>\n");
  std::vector<TargetPair> pairs = readTargetPairs(dir.file("list.xml"));
  ASSERT_EQ(pairs.size(), 2u);
  expectPair(pairs[0], 7, 8);
  expectPair(pairs[1], 5, 6);
  // YAML, the sequence under another name.
  writeText(dir.file("list.yml"), "%YAML:1.0\n---\nimages:\n  - img/l1.png\n  - img/r1.png\n");
  pairs = readTargetPairs(dir.file("list.yml"));
  ASSERT_EQ(pairs.size(), 1u);
  expectPair(pairs[0], 5, 6);
}

TEST(TargetPairs, WhatCannotBePairedOrReadIsNamed) {
  test::TempDir dir;
  EXPECT_EQ(test::errorOf([&] { readTargetPairs(dir.file("absent")); }),
            dir.file("absent") + ": no such folder or image list");
  EXPECT_EQ(test::errorOf([&] { readTargetPairs(dir.path()); }), dir.path() + ": no left<key>/right<key> image pairs");
  writeImage(dir.file("left_1.png"), 1);
  EXPECT_EQ(test::errorOf([&] { readTargetPairs(dir.path()); }),
            dir.file("left_1.png") + ": no right image with the key '1.png' beside it");
  writeImage(dir.file("right_1.png"), 1);
  writeImage(dir.file("right_2.png"), 1);
  EXPECT_EQ(test::errorOf([&] { readTargetPairs(dir.path()); }),
            dir.file("right_2.png") + ": no left image with the key '2.png' beside it");
  writeText(dir.file("left_2.png"), "not a png");
  EXPECT_EQ(test::errorOf([&] { readTargetPairs(dir.path()); }),
            dir.file("left_2.png") + ": cannot read the image (not a PNG or JPEG image)");

  writeText(dir.file("odd.xml"),
            "<?xml version=\"1.0\"?>\n<opencv_storage>\n<imagelist>\n\"left_1.png\"\n</imagelist>\n</opencv_storage>\n");
  EXPECT_EQ(test::errorOf([&] { readTargetPairs(dir.file("odd.xml")); }),
            dir.file("odd.xml") + ": the imagelist has an odd number of names (1); left and right alternate");
  writeText(dir.file("empty.yml"), "%YAML:1.0\n---\nimagelist: []\n");
  EXPECT_EQ(test::errorOf([&] { readTargetPairs(dir.file("empty.yml")); }), dir.file("empty.yml") + ": the imagelist is empty");
  writeText(dir.file("missing.yml"), "%YAML:1.0\n---\nimagelist:\n  - left_1.png\n  - right_9.png\n");
  EXPECT_EQ(test::errorOf([&] { readTargetPairs(dir.file("missing.yml")); }),
            dir.file("missing.yml") + ": imagelist entry 2 (" + dir.file("right_9.png") + "): cannot read the image (no such file)");
  writeText(dir.file("numbers.yml"), "%YAML:1.0\n---\nimagelist:\n  - 1\n  - 2\n");
  EXPECT_EQ(test::errorOf([&] { readTargetPairs(dir.file("numbers.yml")); }),
            dir.file("numbers.yml") + ": imagelist entry 1 is not a file name");
  writeText(dir.file("flat.yml"), "%YAML:1.0\n---\nwidth: 3\n");
  EXPECT_EQ(test::errorOf([&] { readTargetPairs(dir.file("flat.yml")); }),
            dir.file("flat.yml") + ": no sequence of image names (an `imagelist` node)");
  writeText(dir.file("garbage.xml"), "<?xml version=\"1.0\"?>\n<opencv_storage>\n<imagelist>\n\"a\"");
  const std::string garbage = test::errorOf([&] { readTargetPairs(dir.file("garbage.xml")); });
  EXPECT_EQ(garbage.rfind(dir.file("garbage.xml") + ": not an OpenCV image list", 0), 0u) << garbage;
}

}  // namespace
}  // namespace stereoloc
