#pragma once
// Stage 5: field-marking classification (Algorithm 3, Fig. 3.8). A white marking on the dark
// floor shows as two parallel edges of opposite gradient. Our lines are directed (the normal
// points to the bright side), so the partner of a marking edge is searched only on the bright
// side, along the normal, up to W' px: this rejects dark stripes between bright areas. A
// segment is a marking when at least xi_l of its tested pixels (a fraction xi_h of all,
// evenly spaced) have a partner.
//
// W' depends on the row: the widest a marking of width w can appear at image row v is
// f w / x(v), with x(v) the floor distance seen at that row; the frontend passes
// W'(v) = clamp(width_factor * f w / x(v), min_width_px, max_width_px). A wall (50 mm high,
// 5 marking widths) seen at the same distance is then too wide to pass as a marking.
#include <vector>

#include "frontend/features.h"
#include "frontend/gradient.h"
#include "frontend/segments.h"

namespace stereoloc::frontend {

struct ClassifyParams {
  // Width of the field markings on the floor, mm, for W'(v); 0 takes it from the field map
  // (MiroSot 10 mm). A monocular user on another field states it here (RoboCup MSL: 125 mm).
  double marking_width_mm = 0.0;
  double width_factor = 1.6;           // W'(v) relative to the widest expected marking at row v
  double min_width_px = 3.0;           // lower clamp of W' (thin, distant markings)
  double max_width_px = 24.0;          // upper clamp of W'
  double opposite_tolerance_deg = 20.0;  // partner direction vs theta + 180 deg
  double xi_h = 1.0;                   // fraction of the segment's pixels tested
  double xi_l = 0.5;                   // fraction of tested pixels that must have a partner
  // Both outer sides of a marking are floor: a partner only counts when the luma 2 px outside
  // the two edges differs by at most this fraction of the stripe's contrast over the brighter
  // outer side. The top of a wall is a bright strip too, but between the wall face (bright)
  // and the background (grey): without this test wall tops and the top outline were called
  // markings (36 of 37 misclassified matched edges in bench_frontend). <= 0 disables the test.
  double max_outer_difference = 0.5;
  // A tested pixel whose partner search runs out of the observed image (within 2 px of the
  // border) before W' gives no verdict and is not counted: a stripe running out of the image
  // shows its partner edge only where it is inside. A segment needs a verdict on at least this
  // share of its tested pixels to be a marking.
  double min_seen_share = 0.25;
};

// Sets cls, marking_width and marking_score of every segment. max_width_per_row[v] is W'(v);
// an empty vector means min_width_px everywhere. luma (CV_8UC1, the image of grad) enables the
// outer-side test (max_outer_difference); without it only the partner edge is required.
void classifySegments(const GradientStage& grad, const SegmentExtractor& extractor,
                      const std::vector<float>& max_width_per_row, const ClassifyParams& params,
                      std::vector<Segment>& segments, std::vector<float>& scratch, const cv::Mat* luma = nullptr);

}  // namespace stereoloc::frontend
