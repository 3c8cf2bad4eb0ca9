#pragma once
// Minimal 2D plotting with OpenCV for reports: line/point series, shaded bands, horizontal
// reference lines, covariance ellipses, bar charts, the MiroSot field as a backdrop; axes with
// "nice" ticks, labels and a legend. Output PNG, written atomically.
#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "src/core/field_map.h"

namespace stereoloc {

enum class LineStyle { Solid, Dashed, Points };

// A small fixed palette (BGR) for series, distinguishable in print.
cv::Scalar plotColor(size_t index);

class Plot {
 public:
  Plot(std::string title, std::string x_label, std::string y_label, int width_px = 960, int height_px = 640);

  void line(const std::vector<double>& x, const std::vector<double>& y, const std::string& label,
            const cv::Scalar& color, LineStyle style = LineStyle::Solid, int thickness = 2);
  void band(const std::vector<double>& x, const std::vector<double>& lo, const std::vector<double>& hi,
            const std::string& label, const cv::Scalar& color);
  void hline(double y, const std::string& label, const cv::Scalar& color, LineStyle style = LineStyle::Dashed);
  // The n-sigma ellipse of a 2x2 covariance centred at `centre` (data units).
  void ellipse(const Eigen::Vector2d& centre, const Eigen::Matrix2d& covariance, double n_sigma,
               const cv::Scalar& color);
  void segment(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const cv::Scalar& color, int thickness = 1);
  void circle(const Eigen::Vector2d& centre, double radius, const cv::Scalar& color, int thickness = 1);
  void marker(const Eigen::Vector2d& at, const cv::Scalar& color, int size_px = 6);
  // Bars at x = 0, 1, ... with category labels under them.
  void bars(const std::vector<std::string>& categories, const std::vector<double>& values, const cv::Scalar& color);

  void setEqualAspect(bool on) { equal_aspect_ = on; }
  void setLimits(double xmin, double xmax, double ymin, double ymax);

  cv::Mat render() const;
  void savePng(const std::string& path) const;

 private:
  struct Item;
  struct Frame;
  Frame frame() const;  // margins, data limits and scale of render()
  void drawGrid(cv::Mat& img, const Frame& f) const;    // grid lines and tick labels
  void drawItems(cv::Mat& img, const Frame& f) const;   // the series, clipped to the plot area
  void drawLabels(cv::Mat& img, const Frame& f) const;  // categories, title, axis labels
  void drawLegend(cv::Mat& img, const Frame& f) const;
  std::string title_, x_label_, y_label_;
  int width_, height_;
  bool equal_aspect_ = false, fixed_limits_ = false;
  double xmin_ = 0, xmax_ = 1, ymin_ = 0, ymax_ = 1;
  std::vector<std::shared_ptr<Item>> items_;
  std::vector<std::string> categories_;
  std::vector<std::pair<std::string, std::pair<cv::Scalar, LineStyle>>> legend_;
};

// Draws the field's walls, goals and markings (MiroSot geometry) and its landmarks.
void drawField(Plot& plot, const FieldMap& map);

// Tick positions covering [lo, hi] at a 1-2-5 step, about `target` of them.
std::vector<double> niceTicks(double lo, double hi, int target = 6);

}  // namespace stereoloc
