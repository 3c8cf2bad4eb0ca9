#include "src/eval/plot.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <opencv2/imgproc.hpp>

#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/io/image_file.h"

namespace stereoloc {

cv::Scalar plotColor(size_t i) {
  static const cv::Scalar palette[] = {
      {180, 119, 31}, {14, 127, 255}, {44, 160, 44}, {40, 39, 214}, {189, 103, 148},
      {75, 86, 140},  {194, 119, 227}, {127, 127, 127}, {34, 189, 188}, {207, 190, 23}};
  return palette[i % (sizeof(palette) / sizeof(palette[0]))];
}

struct Plot::Item {
  enum Kind { Polyline, Band, HLine, Segment, Circle, Marker, Bars } kind;
  std::vector<Eigen::Vector2d> pts, pts2;
  cv::Scalar color;
  LineStyle style = LineStyle::Solid;
  int thickness = 1;
  double value = 0;
};

Plot::Plot(std::string title, std::string x_label, std::string y_label, int width_px, int height_px)
    : title_(std::move(title)), x_label_(std::move(x_label)), y_label_(std::move(y_label)), width_(width_px),
      height_(height_px) {}

void Plot::line(const std::vector<double>& x, const std::vector<double>& y, const std::string& label,
                const cv::Scalar& color, LineStyle style, int thickness) {
  auto it = std::make_shared<Item>();
  it->kind = Item::Polyline;
  for (size_t i = 0; i < std::min(x.size(), y.size()); ++i)
    if (std::isfinite(x[i]) && std::isfinite(y[i])) it->pts.emplace_back(x[i], y[i]);
  it->color = color;
  it->style = style;
  it->thickness = thickness;
  items_.push_back(it);
  if (!label.empty()) legend_.push_back({label, {color, style}});
}

void Plot::band(const std::vector<double>& x, const std::vector<double>& lo, const std::vector<double>& hi,
                const std::string& label, const cv::Scalar& color) {
  auto it = std::make_shared<Item>();
  it->kind = Item::Band;
  for (size_t i = 0; i < x.size() && i < lo.size() && i < hi.size(); ++i) {
    if (!std::isfinite(x[i]) || !std::isfinite(lo[i]) || !std::isfinite(hi[i])) continue;
    it->pts.emplace_back(x[i], lo[i]);
    it->pts2.emplace_back(x[i], hi[i]);
  }
  it->color = color;
  items_.push_back(it);
  if (!label.empty()) legend_.push_back({label, {color, LineStyle::Solid}});
}

void Plot::hline(double y, const std::string& label, const cv::Scalar& color, LineStyle style) {
  auto it = std::make_shared<Item>();
  it->kind = Item::HLine;
  it->value = y;
  it->color = color;
  it->style = style;
  items_.push_back(it);
  if (!label.empty()) legend_.push_back({label, {color, style}});
}

void Plot::ellipse(const Eigen::Vector2d& centre, const Eigen::Matrix2d& covariance, double n_sigma,
                   const cv::Scalar& color) {
  if (!covariance.allFinite()) return;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(0.5 * (covariance + covariance.transpose()));
  const Eigen::Vector2d ev = es.eigenvalues().cwiseMax(0.0).cwiseSqrt() * n_sigma;
  auto it = std::make_shared<Item>();
  it->kind = Item::Polyline;
  for (int i = 0; i <= 48; ++i) {
    const double a = kTwoPi * i / 48;
    it->pts.push_back(centre + es.eigenvectors() * Eigen::Vector2d(ev(0) * std::cos(a), ev(1) * std::sin(a)));
  }
  it->color = color;
  it->thickness = 1;
  items_.push_back(it);
}

void Plot::segment(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const cv::Scalar& color, int thickness) {
  auto it = std::make_shared<Item>();
  it->kind = Item::Polyline;
  it->pts = {a, b};
  it->color = color;
  it->thickness = thickness;
  items_.push_back(it);
}

void Plot::circle(const Eigen::Vector2d& centre, double radius, const cv::Scalar& color, int thickness) {
  auto it = std::make_shared<Item>();
  it->kind = Item::Polyline;
  for (int i = 0; i <= 96; ++i) {
    const double a = kTwoPi * i / 96;
    it->pts.push_back(centre + radius * Eigen::Vector2d(std::cos(a), std::sin(a)));
  }
  it->color = color;
  it->thickness = thickness;
  items_.push_back(it);
}

void Plot::marker(const Eigen::Vector2d& at, const cv::Scalar& color, int size_px) {
  auto it = std::make_shared<Item>();
  it->kind = Item::Marker;
  it->pts = {at};
  it->color = color;
  it->thickness = size_px;
  items_.push_back(it);
}

void Plot::bars(const std::vector<std::string>& categories, const std::vector<double>& values, const cv::Scalar& color) {
  auto it = std::make_shared<Item>();
  it->kind = Item::Bars;
  for (size_t i = 0; i < values.size(); ++i) it->pts.emplace_back(static_cast<double>(i), values[i]);
  it->color = color;
  items_.push_back(it);
  categories_ = categories;
}

void Plot::setLimits(double xmin, double xmax, double ymin, double ymax) {
  if (!(xmax > xmin && ymax > ymin)) throw Error("plot: empty limits");
  fixed_limits_ = true;
  xmin_ = xmin;
  xmax_ = xmax;
  ymin_ = ymin;
  ymax_ = ymax;
}

std::vector<double> niceTicks(double lo, double hi, int target) {
  std::vector<double> ticks;
  if (!(hi > lo) || !std::isfinite(lo) || !std::isfinite(hi)) return ticks;
  const double raw = (hi - lo) / std::max(1, target);
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  double step = mag;
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (m * mag >= raw) {
      step = m * mag;
      break;
    }
  for (double t = std::ceil(lo / step) * step; t <= hi + 1e-9 * step; t += step) ticks.push_back(std::fabs(t) < 1e-12 * step ? 0.0 : t);
  return ticks;
}

namespace {

std::string tickLabel(double v, double step) {
  char buf[32];
  const int decimals = step >= 1 ? 0 : static_cast<int>(std::ceil(-std::log10(step) - 1e-9));
  std::snprintf(buf, sizeof(buf), "%.*f", std::min(decimals, 6), v);
  return buf;
}

void dashedLine(cv::Mat& img, cv::Point2d a, cv::Point2d b, const cv::Scalar& c, int thickness) {
  const double len = cv::norm(b - a);
  const int n = std::max(1, static_cast<int>(len / 8));
  for (int i = 0; i < n; i += 2) {
    const cv::Point2d p = a + (b - a) * (static_cast<double>(i) / n), q = a + (b - a) * (std::min(i + 1.0, 1.0 * n) / n);
    cv::line(img, p, q, c, thickness, cv::LINE_AA);
  }
}

}  // namespace

// Where data lands on the image: the plot area's margins and size (px), the data limits and the
// scale (px per unit), the tick range (x_hi, y_hi: the data limits, or with equal aspect the
// data at the area's far edges).
struct Plot::Frame {
  int left = 90, right = 20, top = 50, bottom = 70;
  double pw = 0, ph = 0, xmin = 0, xmax = 1, ymin = 0, ymax = 1, sx = 1, sy = 1, x_hi = 1, y_hi = 1;
  cv::Point2d toPx(const Eigen::Vector2d& p) const {
    return cv::Point2d(left + (p.x() - xmin) * sx, top + ph - (p.y() - ymin) * sy);
  }
  cv::Rect area() const { return cv::Rect(left, top, static_cast<int>(pw), static_cast<int>(ph)); }
};

namespace {
const cv::Scalar kGridColour(225, 225, 225), kAxisColour(60, 60, 60), kTextColour(30, 30, 30);
}  // namespace

Plot::Frame Plot::frame() const {
  Frame f;
  f.bottom = categories_.empty() ? 70 : 110;
  double xmin = xmin_, xmax = xmax_, ymin = ymin_, ymax = ymax_;
  if (!fixed_limits_) {
    xmin = ymin = std::numeric_limits<double>::infinity();
    xmax = ymax = -std::numeric_limits<double>::infinity();
    auto grow = [&](const Eigen::Vector2d& p) {
      xmin = std::min(xmin, p.x());
      xmax = std::max(xmax, p.x());
      ymin = std::min(ymin, p.y());
      ymax = std::max(ymax, p.y());
    };
    for (const auto& it : items_) {
      for (const auto& p : it->pts) grow(p);
      for (const auto& p : it->pts2) grow(p);
      if (it->kind == Item::HLine) {
        ymin = std::min(ymin, it->value);
        ymax = std::max(ymax, it->value);
      }
      if (it->kind == Item::Bars) {
        ymin = std::min(ymin, 0.0);
        xmin = std::min(xmin, -0.6);
        xmax = std::max(xmax, it->pts.size() - 0.4);
      }
    }
    if (!std::isfinite(xmin)) xmin = 0, xmax = 1, ymin = 0, ymax = 1;
    if (xmax - xmin < 1e-12) xmin -= 0.5, xmax += 0.5;
    if (ymax - ymin < 1e-12) ymin -= 0.5, ymax += 0.5;
    const double px = 0.03 * (xmax - xmin), py = 0.05 * (ymax - ymin);
    xmin -= px, xmax += px, ymin -= py, ymax += py;
  }
  f.xmin = xmin, f.xmax = xmax, f.ymin = ymin, f.ymax = ymax;
  f.pw = width_ - f.left - f.right;
  f.ph = height_ - f.top - f.bottom;
  f.sx = f.pw / (xmax - xmin);
  f.sy = f.ph / (ymax - ymin);
  if (equal_aspect_) {
    const double s = std::min(f.sx, f.sy);
    f.sx = f.sy = s;
  }
  f.x_hi = equal_aspect_ ? xmin + f.pw / f.sx : xmax;
  f.y_hi = equal_aspect_ ? ymin + f.ph / f.sy : ymax;
  return f;
}

void Plot::drawGrid(cv::Mat& img, const Frame& f) const {
  const auto xt = categories_.empty() ? niceTicks(f.xmin, f.x_hi) : std::vector<double>{};
  const auto yt = niceTicks(f.ymin, f.y_hi);
  for (double t : xt) {
    const cv::Point2d p = f.toPx({t, f.ymin});
    cv::line(img, {static_cast<int>(p.x), f.top}, {static_cast<int>(p.x), f.top + static_cast<int>(f.ph)}, kGridColour, 1);
    const std::string s = tickLabel(t, xt.size() > 1 ? xt[1] - xt[0] : 1);
    cv::putText(img, s, {static_cast<int>(p.x) - 4 * static_cast<int>(s.size()), f.top + static_cast<int>(f.ph) + 20},
                cv::FONT_HERSHEY_SIMPLEX, 0.45, kTextColour, 1, cv::LINE_AA);
  }
  for (double t : yt) {
    const cv::Point2d p = f.toPx({f.xmin, t});
    cv::line(img, {f.left, static_cast<int>(p.y)}, {f.left + static_cast<int>(f.pw), static_cast<int>(p.y)}, kGridColour, 1);
    const std::string s = tickLabel(t, yt.size() > 1 ? yt[1] - yt[0] : 1);
    cv::putText(img, s, {f.left - 10 - 8 * static_cast<int>(s.size()), static_cast<int>(p.y) + 5},
                cv::FONT_HERSHEY_SIMPLEX, 0.45, kTextColour, 1, cv::LINE_AA);
  }
}

// The items are drawn on a copy of the whole image, of which only the plot area is kept: what
// falls outside it is clipped.
void Plot::drawItems(cv::Mat& img, const Frame& f) const {
  cv::Mat canvas = img.clone();
  for (const auto& it : items_) {
    switch (it->kind) {
      case Item::Band: {
        std::vector<cv::Point> poly;
        for (const auto& p : it->pts) poly.push_back(f.toPx(p));
        for (auto r = it->pts2.rbegin(); r != it->pts2.rend(); ++r) poly.push_back(f.toPx(*r));
        if (poly.size() >= 3) {
          cv::Mat overlay = canvas.clone();
          cv::fillPoly(overlay, std::vector<std::vector<cv::Point>>{poly}, it->color, cv::LINE_AA);
          cv::addWeighted(overlay, 0.25, canvas, 0.75, 0, canvas);
        }
        break;
      }
      case Item::Polyline:
        for (size_t i = 0; i < it->pts.size(); ++i) {
          if (it->style == LineStyle::Points) {
            cv::circle(canvas, f.toPx(it->pts[i]), 2, it->color, cv::FILLED, cv::LINE_AA);
          } else if (i > 0) {
            if (it->style == LineStyle::Dashed)
              dashedLine(canvas, f.toPx(it->pts[i - 1]), f.toPx(it->pts[i]), it->color, it->thickness);
            else
              cv::line(canvas, f.toPx(it->pts[i - 1]), f.toPx(it->pts[i]), it->color, it->thickness, cv::LINE_AA);
          }
        }
        break;
      case Item::HLine: {
        const cv::Point2d a = f.toPx({f.xmin, it->value}), b = f.toPx({f.x_hi, it->value});
        if (it->style == LineStyle::Dashed) dashedLine(canvas, a, b, it->color, 1);
        else cv::line(canvas, a, b, it->color, 1, cv::LINE_AA);
        break;
      }
      case Item::Marker: {
        const cv::Point2d p = f.toPx(it->pts[0]);
        const int s = it->thickness;
        cv::line(canvas, p - cv::Point2d(s, 0), p + cv::Point2d(s, 0), it->color, 2, cv::LINE_AA);
        cv::line(canvas, p - cv::Point2d(0, s), p + cv::Point2d(0, s), it->color, 2, cv::LINE_AA);
        break;
      }
      case Item::Bars:
        for (const auto& p : it->pts) {
          const cv::Point2d a = f.toPx({p.x() - 0.35, 0.0}), b = f.toPx({p.x() + 0.35, p.y()});
          cv::rectangle(canvas, a, b, it->color, cv::FILLED);
          char buf[32];
          std::snprintf(buf, sizeof(buf), "%.3g", p.y());
          cv::putText(canvas, buf, {static_cast<int>(a.x), static_cast<int>(b.y) - 6}, cv::FONT_HERSHEY_SIMPLEX, 0.45,
                      kTextColour, 1, cv::LINE_AA);
        }
        break;
      default:
        break;
    }
  }
  canvas(f.area()).copyTo(img(f.area()));
}

void Plot::drawLabels(cv::Mat& img, const Frame& f) const {
  for (size_t i = 0; i < categories_.size(); ++i) {
    const cv::Point2d p = f.toPx({static_cast<double>(i), f.ymin});
    cv::putText(img, categories_[i],
                {static_cast<int>(p.x) - 4 * static_cast<int>(categories_[i].size()), f.top + static_cast<int>(f.ph) + 22},
                cv::FONT_HERSHEY_SIMPLEX, 0.5, kTextColour, 1, cv::LINE_AA);
  }
  cv::putText(img, title_, {f.left, 30}, cv::FONT_HERSHEY_SIMPLEX, 0.65, kTextColour, 1, cv::LINE_AA);
  cv::putText(img, x_label_, {f.left + static_cast<int>(f.pw / 2) - 4 * static_cast<int>(x_label_.size()), height_ - 18},
              cv::FONT_HERSHEY_SIMPLEX, 0.55, kTextColour, 1, cv::LINE_AA);
  cv::Mat ylab(24, 20 + 11 * static_cast<int>(y_label_.size()), CV_8UC3, cv::Scalar(255, 255, 255));
  cv::putText(ylab, y_label_, {2, 17}, cv::FONT_HERSHEY_SIMPLEX, 0.55, kTextColour, 1, cv::LINE_AA);
  cv::rotate(ylab, ylab, cv::ROTATE_90_COUNTERCLOCKWISE);
  const int ly = std::max(0, f.top + static_cast<int>(f.ph / 2) - ylab.rows / 2);
  if (ly + ylab.rows <= img.rows && ylab.cols + 4 <= img.cols) ylab.copyTo(img(cv::Rect(4, ly, ylab.cols, ylab.rows)));
}

void Plot::drawLegend(cv::Mat& img, const Frame& f) const {
  int ly = f.top + 18;
  for (const auto& [label, cs] : legend_) {
    const int x0 = f.left + static_cast<int>(f.pw) - 230;
    cv::rectangle(img, {x0 - 6, ly - 14}, {x0 + 224, ly + 6}, cv::Scalar(255, 255, 255), cv::FILLED);
    if (cs.second == LineStyle::Points) cv::circle(img, {x0 + 14, ly - 4}, 3, cs.first, cv::FILLED, cv::LINE_AA);
    else if (cs.second == LineStyle::Dashed)
      dashedLine(img, cv::Point2d(x0, ly - 4.0), cv::Point2d(x0 + 28.0, ly - 4.0), cs.first, 2);
    else cv::line(img, {x0, ly - 4}, {x0 + 28, ly - 4}, cs.first, 2, cv::LINE_AA);
    cv::putText(img, label, {x0 + 36, ly}, cv::FONT_HERSHEY_SIMPLEX, 0.45, kTextColour, 1, cv::LINE_AA);
    ly += 20;
  }
}

cv::Mat Plot::render() const {
  cv::Mat img(height_, width_, CV_8UC3, cv::Scalar(255, 255, 255));
  const Frame f = frame();
  drawGrid(img, f);
  drawItems(img, f);
  cv::rectangle(img, f.area(), kAxisColour, 1);
  drawLabels(img, f);
  drawLegend(img, f);
  return img;
}

void Plot::savePng(const std::string& path) const {
  writePngFile(path, render());
}

void drawField(Plot& plot, const FieldMap& map) {
  const cv::Scalar wall(90, 90, 90), marking(150, 150, 150), blue(200, 80, 0), yellow(0, 190, 220);
  if (map.geometry()) {
    const FieldGeometry& g = *map.geometry();
    const double L = g.length, W = g.width, cy = 0.5 * W, t = g.corner_triangle;
    const std::vector<Eigen::Vector2d> outline = {{t, 0}, {L - t, 0}, {L, t}, {L, W - t}, {L - t, W}, {t, W}, {0, W - t}, {0, t}, {t, 0}};
    for (size_t i = 1; i < outline.size(); ++i) plot.segment(outline[i - 1], outline[i], wall, 2);
    for (double sgn : {0.0, 1.0}) {
      const double x0 = sgn * L, dir = sgn > 0 ? 1 : -1;
      const cv::Scalar gc = sgn > 0 ? yellow : blue;
      const double y0 = cy - 0.5 * g.goal_width, y1 = cy + 0.5 * g.goal_width;
      plot.segment({x0, y0}, {x0 + dir * g.goal_depth, y0}, gc, 2);
      plot.segment({x0 + dir * g.goal_depth, y0}, {x0 + dir * g.goal_depth, y1}, gc, 2);
      plot.segment({x0 + dir * g.goal_depth, y1}, {x0, y1}, gc, 2);
      for (auto [d, w] : {std::pair{g.goal_area_depth, g.goal_area_width}, std::pair{g.penalty_area_depth, g.penalty_area_width}}) {
        const double xi = x0 - dir * d;
        plot.segment({x0, cy - w / 2}, {xi, cy - w / 2}, marking);
        plot.segment({xi, cy - w / 2}, {xi, cy + w / 2}, marking);
        plot.segment({xi, cy + w / 2}, {x0, cy + w / 2}, marking);
      }
    }
    plot.segment({L / 2, 0}, {L / 2, W}, marking);
    plot.circle({L / 2, cy}, g.centre_circle_radius, marking);
  }
  for (const Landmark& l : map.landmarks()) {
    const cv::Scalar c = l.color == GoalColor::Blue ? blue : l.color == GoalColor::Yellow ? yellow : cv::Scalar(60, 60, 60);
    plot.marker(l.xy(), c, l.unique ? 7 : 4);
  }
}

}  // namespace stereoloc
