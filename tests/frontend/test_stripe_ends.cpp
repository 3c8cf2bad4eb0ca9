// trimStripeEnds on synthetic stripes: an end carried past the stripe by a floor edge moves to
// where the stripe stops; an end inside a crossing bar, and a stripe continuing beyond an
// occluder, stay; a short bright piece beyond an occluder is dropped. With extend_px an end
// short of a fading stripe's end moves out to it (up to the image border), and a floor edge or
// a crossing bar beyond the end does not carry it on.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "frontend/stripe_ends.h"

namespace stereoloc::frontend {
namespace {

constexpr double kPi = 3.14159265358979323846;

// A horizontal marking centre line on row y from column x0 to x1 (t runs along -x here: the
// point at t is (rho cos theta - t sin theta, rho sin theta + t cos theta) with theta = pi / 2).
LineFeature horizontal(double y, double x0, double x1, double width) {
  LineFeature l;
  l.theta = kPi / 2;
  l.rho = y;
  l.t_min = -x1;
  l.t_max = -x0;
  l.marking = true;
  l.width = width;
  return l;
}

double xMin(const LineFeature& l) { return -l.t_max; }
double xMax(const LineFeature& l) { return -l.t_min; }

cv::Mat floorImage() { return cv::Mat(120, 240, CV_8UC1, cv::Scalar(90)); }

class StripeEnds : public ::testing::Test {
 protected:
  StripeEndScratch scratch_;
};

StripeEndParams on() {
  StripeEndParams p;
  p.enabled = true;
  return p;
}

TEST_F(StripeEnds, AnEndCarriedPastTheStripeMovesToWhereItStops) {
  cv::Mat img = floorImage();
  cv::rectangle(img, cv::Point(20, 58), cv::Point(139, 62), cv::Scalar(200), cv::FILLED);  // stripe x 20..139
  // A step of the floor in line with the stripe's lower edge carries the edge on to x = 200.
  cv::rectangle(img, cv::Point(140, 63), cv::Point(200, 80), cv::Scalar(60), cv::FILLED);
  std::vector<LineFeature> lines{horizontal(60, 20, 200, 5)};
  trimStripeEnds(img, on(), lines, scratch_);
  EXPECT_NEAR(xMin(lines[0]), 20.0, 1.0);
  EXPECT_NEAR(xMax(lines[0]), 139.5, 1.0);
}

TEST_F(StripeEnds, OffLeavesTheEnds) {
  cv::Mat img = floorImage();
  cv::rectangle(img, cv::Point(20, 58), cv::Point(139, 62), cv::Scalar(200), cv::FILLED);
  std::vector<LineFeature> lines{horizontal(60, 20, 200, 5)};
  trimStripeEnds(img, StripeEndParams(), lines, scratch_);
  EXPECT_DOUBLE_EQ(xMax(lines[0]), 200.0);
}

TEST_F(StripeEnds, AnEndInsideACrossingBarStays) {
  cv::Mat img = floorImage();
  cv::rectangle(img, cv::Point(20, 58), cv::Point(150, 62), cv::Scalar(200), cv::FILLED);
  cv::rectangle(img, cv::Point(140, 10), cv::Point(160, 110), cv::Scalar(200), cv::FILLED);  // a wide bar
  std::vector<LineFeature> lines{horizontal(60, 20, 150, 5)};
  trimStripeEnds(img, on(), lines, scratch_);
  EXPECT_NEAR(xMax(lines[0]), 150.0, 0.01);
}

TEST_F(StripeEnds, AStripeSeenBeyondAnOccluderKeepsItsEndAShortBrightPieceDoesNot) {
  cv::Mat img = floorImage();
  cv::rectangle(img, cv::Point(20, 58), cv::Point(200, 62), cv::Scalar(200), cv::FILLED);
  cv::rectangle(img, cv::Point(100, 30), cv::Point(119, 90), cv::Scalar(20), cv::FILLED);  // a robot, 20 px
  std::vector<LineFeature> lines{horizontal(60, 20, 200, 5)};
  trimStripeEnds(img, on(), lines, scratch_);
  EXPECT_NEAR(xMax(lines[0]), 200.0, 0.01) << "80 px of stripe beyond a 20 px occluder";

  cv::Mat img2 = floorImage();
  cv::rectangle(img2, cv::Point(20, 58), cv::Point(200, 62), cv::Scalar(200), cv::FILLED);
  cv::rectangle(img2, cv::Point(150, 30), cv::Point(189, 90), cv::Scalar(20), cv::FILLED);  // 40 px, 10 px beyond
  std::vector<LineFeature> lines2{horizontal(60, 20, 200, 5)};
  trimStripeEnds(img2, on(), lines2, scratch_);
  EXPECT_NEAR(xMax(lines2[0]), 149.5, 1.0);
}

TEST_F(StripeEnds, OtherLinesAndFaintStripesAreLeftAlone) {
  cv::Mat img = floorImage();
  cv::rectangle(img, cv::Point(20, 58), cv::Point(139, 62), cv::Scalar(93), cv::FILLED);  // 3 grey levels
  std::vector<LineFeature> lines{horizontal(60, 20, 200, 5), horizontal(60, 20, 200, 5)};
  lines[1].marking = false;
  trimStripeEnds(img, on(), lines, scratch_);
  EXPECT_DOUBLE_EQ(xMax(lines[0]), 200.0);
  EXPECT_DOUBLE_EQ(xMax(lines[1]), 200.0);
}

StripeEndParams extending(bool trim) {
  StripeEndParams p;
  p.enabled = trim;
  p.extend_px = 80.0;
  return p;
}

// A stripe of luma 200 on the 90 floor from x = 20 to 149 that goes on fainter (150) to x = 199,
// as a far stripe fades: the edge pixels stopped at x = 150.
cv::Mat fadingStripe() {
  cv::Mat img = floorImage();
  cv::rectangle(img, cv::Point(20, 58), cv::Point(149, 62), cv::Scalar(200), cv::FILLED);
  cv::rectangle(img, cv::Point(150, 58), cv::Point(199, 62), cv::Scalar(150), cv::FILLED);
  return img;
}

TEST_F(StripeEnds, AnEndShortOfAFadingStripeMovesOutToWhereItStops) {
  const cv::Mat img = fadingStripe();
  for (const bool trim : {false, true}) {
    std::vector<LineFeature> lines{horizontal(60, 20, 150, 5)};
    trimStripeEnds(img, extending(trim), lines, scratch_);
    EXPECT_NEAR(xMax(lines[0]), 199.5, 1.0) << "trim " << trim;
    EXPECT_NEAR(xMin(lines[0]), 20.0, 1.0) << "trim " << trim;
  }
  std::vector<LineFeature> lines{horizontal(60, 20, 150, 5)};
  trimStripeEnds(img, on(), lines, scratch_);  // extend_px 0
  EXPECT_DOUBLE_EQ(xMax(lines[0]), 150.0);
}

TEST_F(StripeEnds, AnExtendedEndStopsAtTheImageBorder) {
  cv::Mat img = floorImage();
  cv::rectangle(img, cv::Point(20, 58), cv::Point(239, 62), cv::Scalar(200), cv::FILLED);  // to the right border
  std::vector<LineFeature> lines{horizontal(60, 20, 190, 5)};
  trimStripeEnds(img, extending(true), lines, scratch_);
  EXPECT_GE(xMax(lines[0]), 237.0);
  EXPECT_LE(xMax(lines[0]), 239.5);
}

TEST_F(StripeEnds, AFloorEdgeOrACrossingBarBeyondTheEndDoesNotExtendIt) {
  cv::Mat img = floorImage();
  cv::rectangle(img, cv::Point(20, 58), cv::Point(139, 62), cv::Scalar(200), cv::FILLED);
  cv::rectangle(img, cv::Point(140, 63), cv::Point(200, 80), cv::Scalar(60), cv::FILLED);  // a floor step in line
  std::vector<LineFeature> lines{horizontal(60, 20, 139.5, 5)};
  trimStripeEnds(img, extending(true), lines, scratch_);
  EXPECT_NEAR(xMax(lines[0]), 139.5, 1.0);

  cv::Mat bar = floorImage();
  cv::rectangle(bar, cv::Point(20, 58), cv::Point(139, 62), cv::Scalar(200), cv::FILLED);
  cv::rectangle(bar, cv::Point(140, 10), cv::Point(160, 110), cv::Scalar(200), cv::FILLED);  // a wide bar
  std::vector<LineFeature> bar_lines{horizontal(60, 20, 139.5, 5)};
  trimStripeEnds(bar, extending(false), bar_lines, scratch_);
  EXPECT_NEAR(xMax(bar_lines[0]), 139.5, 1.0);
}

}  // namespace
}  // namespace stereoloc::frontend
