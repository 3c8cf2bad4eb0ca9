#pragma once
// Reading an image file so that a damaged one is named with what is wrong with it.
//
// The file is read once; a PNG's chunk structure (lengths, CRC-32 of every chunk, IHDR first,
// IEND reached) and a JPEG's marker structure (segments within the file, an end-of-image marker
// after the last scan) are checked before OpenCV decodes the bytes. A cut-short or bit-flipped
// file is then refused with its defect and the byte it sits at, and the codec libraries never
// see it: libpng would print its own line on stderr and libjpeg would return a cut-short JPEG's
// missing rows as grey without a word. Other formats go to OpenCV as they are.
#include <opencv2/core/mat.hpp>
#include <string>
#include <vector>

namespace stereoloc {

struct ImageRead {
  cv::Mat image;        // empty when the file could not be read
  std::string problem;  // empty on success, else a short reason ("no such file", "PNG ...")
};

// `imread_flags` as for cv::imread (cv::IMREAD_UNCHANGED, cv::IMREAD_GRAYSCALE, ...).
ImageRead readImageFile(const std::string& path, int imread_flags);

// The container check alone: empty when the bytes' PNG or JPEG structure is sound (or they are
// neither), else the defect.
std::string imageContainerDefect(const std::vector<unsigned char>& bytes);

}  // namespace stereoloc
