#pragma once
// Reading an image file so that a damaged one is named with what is wrong with it.
//
// The file is read once and checked before it is decoded (src/io/image_codec.h): a PNG's chunk
// structure (lengths, the CRC-32 of every chunk, IHDR first, IEND reached); a JPEG's marker
// structure (segments within the file, an end-of-image marker after the last scan), then its
// scan decoded once by libjpeg at 1/8 scale with the corrupt-data warnings as errors (0.05 ms
// for a 320x240 frame). A cut-short or corrupt file is refused with its defect (and the byte it
// sits at) instead of decoding with grey or garbled rows. A JPEG's scan carries no checksum:
// what libjpeg decodes without complaint passes. PNG and JPEG are read; other formats are refused.
#include <opencv2/core/mat.hpp>
#include <string>
#include <vector>

#include "src/io/image_codec.h"

namespace stereoloc {

struct ImageRead {
  cv::Mat image;        // empty when the file could not be read
  std::string problem;  // empty on success, else a short reason ("no such file", "PNG ...")
};

ImageRead readImageFile(const std::string& path, ImageColour colour);

// Writes `image` as a PNG (encodePng) through a temporary file renamed into place; throws Error
// naming the path.
void writePngFile(const std::string& path, const cv::Mat& image);

// The container check alone: empty when the bytes' PNG or JPEG structure is sound (or they are
// neither), else the defect.
std::string imageContainerDefect(const std::vector<unsigned char>& bytes);

}  // namespace stereoloc
