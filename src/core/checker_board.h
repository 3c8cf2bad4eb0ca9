#pragma once
// A planar checkerboard calibration target: `columns` x `rows` inner corners (the corners where
// four squares meet, what cv::findChessboardCorners finds), squares `square_mm` on a side.
//
// Board frame (mm): origin at the first inner corner, x along a row of corners, y along a
// column, z = 0 on the board (OpenCV's convention for object points). Corner (i, j), column i
// and row j, is at (i s, j s, 0), listed row by row: the order cv::findChessboardCorners reports
// for a board seen upright. The board's outer squares extend one square beyond the inner
// corners on every side, and a white margin of one more square surrounds them (the quiet zone
// the detector needs).
#include <opencv2/core/types.hpp>
#include <string>
#include <vector>

#include "src/core/error.h"

namespace stereoloc {

struct CheckerBoard {
  int columns = 9;          // inner corners per row, >= 3
  int rows = 6;             // inner corners per column, >= 3; columns != rows so a view has one orientation
  double square_mm = 15.0;  // side of a square, mm

  cv::Size patternSize() const { return cv::Size(columns, rows); }

  // Inner corners in the board frame, row by row.
  std::vector<cv::Point3f> corners() const {
    std::vector<cv::Point3f> out;
    out.reserve(static_cast<size_t>(columns) * static_cast<size_t>(rows));
    for (int j = 0; j < rows; ++j)
      for (int i = 0; i < columns; ++i)
        out.emplace_back(static_cast<float>(i * square_mm), static_cast<float>(j * square_mm), 0.0f);
    return out;
  }

  // Throws Error naming `where` and the field: fewer than 3 corners a side, equal sides (the
  // detector's corner order would be ambiguous under rotation), or a square that is not a
  // positive, finite length.
  void validate(const std::string& where) const {
    if (columns < 3) throw Error(where + ": columns: a board needs at least 3 inner corners per row, got " + std::to_string(columns));
    if (rows < 3) throw Error(where + ": rows: a board needs at least 3 inner corners per column, got " + std::to_string(rows));
    if (columns == rows)
      throw Error(where + ": columns, rows: equal sides (" + std::to_string(columns) +
                  ") make the corner order ambiguous; use a board with unequal sides");
    if (!(square_mm > 0.0) || !(square_mm < 1e6))
      throw Error(where + ": square_mm: must be a positive length in mm, got " + std::to_string(square_mm));
  }
};

}  // namespace stereoloc
