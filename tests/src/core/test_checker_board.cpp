#include "src/core/checker_board.h"

#include <gtest/gtest.h>

#include "test_util.h"

namespace stereoloc {
namespace {

TEST(CheckerBoard, CornersRowByRowFromTheFirstInnerCorner) {
  CheckerBoard b;
  b.columns = 4;
  b.rows = 3;
  b.square_mm = 20.0;
  const std::vector<cv::Point3f> c = b.corners();
  ASSERT_EQ(c.size(), 12u);
  EXPECT_EQ(c[0], cv::Point3f(0, 0, 0));
  EXPECT_EQ(c[1], cv::Point3f(20, 0, 0));  // along a row first
  EXPECT_EQ(c[4], cv::Point3f(0, 20, 0));  // then the next row
  EXPECT_EQ(c[11], cv::Point3f(60, 40, 0));
  EXPECT_EQ(b.patternSize(), cv::Size(4, 3));
}

TEST(CheckerBoard, InvalidBoardsNameTheField) {
  CheckerBoard b;
  EXPECT_EQ(test::errorOf([&] { b.validate("board"); }), "");
  b.columns = 2;
  EXPECT_NE(test::errorOf([&] { b.validate("board"); }).find("board: columns:"), std::string::npos);
  b = CheckerBoard();
  b.rows = 1;
  EXPECT_NE(test::errorOf([&] { b.validate("board"); }).find("board: rows:"), std::string::npos);
  b = CheckerBoard();
  b.rows = b.columns;
  EXPECT_NE(test::errorOf([&] { b.validate("board"); }).find("equal sides"), std::string::npos);
  b = CheckerBoard();
  b.square_mm = -1.0;
  EXPECT_NE(test::errorOf([&] { b.validate("board"); }).find("board: square_mm:"), std::string::npos);
  b.square_mm = std::nan("");
  EXPECT_NE(test::errorOf([&] { b.validate("board"); }).find("board: square_mm:"), std::string::npos);
}

}  // namespace
}  // namespace stereoloc
