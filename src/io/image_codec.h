#pragma once
// PNG and JPEG images to and from bytes, with libpng and libjpeg: what the datasets, the
// renderer, the calibration views and the plots are written in, and what cameras and photographs
// deliver. Colour comes in OpenCV's channel order (BGR, BGRA). These two formats only: OpenCV's
// own codecs module would bring GDAL and some hundred libraries into every process that reads an
// image (a tenth of a second to start `stereoloc`).
//
// EXIF orientation tags are not applied: a camera's frames are used as the sensor delivered them.
#include <opencv2/core/mat.hpp>
#include <string>
#include <vector>

namespace stereoloc {

enum class ImageColour {
  AsStored,  // as the file holds it: grey (1 channel), BGR or BGRA; 8 or 16 bits per channel
  Grey,      // 8-bit, one channel (a colour image's luma)
  Bgr,       // 8-bit BGR (a grey image repeated in three channels, alpha dropped)
};

// Whether the bytes open as a PNG (its 8-byte signature) or a JPEG (SOI and a marker).
bool isPngImage(const std::vector<unsigned char>& bytes);
bool isJpegImage(const std::vector<unsigned char>& bytes);

// Decodes a PNG or JPEG image. Throws Error with a short reason when the bytes are neither or do
// not decode.
cv::Mat decodeImage(const std::vector<unsigned char>& bytes, ImageColour colour);

// The PNG of an 8- or 16-bit image of 1 (grey), 3 (BGR) or 4 (BGRA) channels, compressed for
// speed (zlib level 1: the renderer writes thousands). Throws Error for any other image.
std::vector<unsigned char> encodePng(const cv::Mat& image);

// The JPEG's scan decoded once at 1/8 scale (the entropy-coded data is read whole at any scale)
// with libjpeg's corrupt-data warnings as errors: empty when it decodes cleanly, else the defect.
std::string jpegScanDefect(const std::vector<unsigned char>& bytes);

}  // namespace stereoloc
