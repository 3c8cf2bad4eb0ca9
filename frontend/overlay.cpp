#include "frontend/overlay.h"

#include <opencv2/imgproc.hpp>
#include <string>

#include "src/core/error.h"

namespace stereoloc::frontend {
namespace {

const cv::Scalar kMarking(0, 0, 255), kOther(0, 200, 0), kEdge(0, 140, 255), kL(0, 0, 255), kT(255, 80, 0),
    kX(255, 0, 255), kGoal(0, 255, 255);

void marker(cv::Mat& img, cv::Point p, LandmarkType type) {
  switch (type) {
    case LandmarkType::MarkingCorner: cv::drawMarker(img, p, kL, cv::MARKER_SQUARE, 11, 2); break;
    case LandmarkType::Junction: cv::drawMarker(img, p, kT, cv::MARKER_TRIANGLE_UP, 13, 2); break;
    case LandmarkType::Intersection: cv::drawMarker(img, p, kX, cv::MARKER_TILTED_CROSS, 13, 2); break;
    case LandmarkType::GoalCorner: cv::drawMarker(img, p, kGoal, cv::MARKER_DIAMOND, 13, 2); break;
    default: cv::drawMarker(img, p, cv::Scalar(255, 255, 255), cv::MARKER_CROSS, 9, 1); break;
  }
}

}  // namespace

cv::Mat drawDetections(const cv::Mat& bgr, const FrontendResult& r, int scale) {
  if (scale < 1) throw Error("overlay: scale must be at least 1, got " + std::to_string(scale));
  if (bgr.empty() || bgr.type() != CV_8UC3) throw Error("overlay: expected a CV_8UC3 image");
  cv::Mat img;
  cv::resize(bgr, img, cv::Size(), scale, scale, cv::INTER_NEAREST);
  // Pixel centres at integer coordinates: pixel (x, y) covers [x - 0.5, x + 0.5) before scaling.
  auto P = [scale](double x, double y) {
    return cv::Point(static_cast<int>(std::lround((x + 0.5) * scale - 0.5)), static_cast<int>(std::lround((y + 0.5) * scale - 0.5)));
  };
  for (const Segment& s : r.segments)
    if (s.cls == SegmentClass::Marking) cv::line(img, P(s.x1, s.y1), P(s.x2, s.y2), kEdge, 1, cv::LINE_AA);
  for (const LineFeature& l : r.lines)
    cv::line(img, P(l.x(l.t_min), l.y(l.t_min)), P(l.x(l.t_max), l.y(l.t_max)), l.marking ? kMarking : kOther,
             l.marking ? 2 : 1, cv::LINE_AA);
  for (const PointFeature& f : r.features) marker(img, P(f.u, f.v), f.type);
  const struct {
    const char* text;
    cv::Scalar colour;
    int kind;  // 0 line, 1..4 marker types
  } legend[] = {{"marking", kMarking, 0}, {"other edge", kOther, 0}, {"L corner", kL, 1},
                {"T junction", kT, 2},    {"X intersection", kX, 3}, {"goal corner", kGoal, 4}};
  cv::rectangle(img, cv::Rect(2, 2, 128, 16 * 6 + 6), cv::Scalar(0, 0, 0), cv::FILLED);
  for (int i = 0; i < 6; ++i) {
    const int y = 14 + 16 * i;
    if (legend[i].kind == 0) {
      cv::line(img, cv::Point(8, y - 4), cv::Point(24, y - 4), legend[i].colour, 2);
    } else {
      const LandmarkType t[] = {LandmarkType::MarkingCorner, LandmarkType::Junction, LandmarkType::Intersection,
                                LandmarkType::GoalCorner};
      marker(img, cv::Point(16, y - 4), t[legend[i].kind - 1]);
    }
    cv::putText(img, legend[i].text, cv::Point(30, y), cv::FONT_HERSHEY_PLAIN, 0.9, legend[i].colour, 1, cv::LINE_AA);
  }
  return img;
}

}  // namespace stereoloc::frontend
