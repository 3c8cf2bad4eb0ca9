#include "src/io/image_file.h"

#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <opencv2/core.hpp>
#include <system_error>

#include "src/core/atomic_file.h"
#include "src/core/error.h"
#include "src/io/image_codec.h"

namespace stereoloc {
namespace {

using Bytes = std::vector<unsigned char>;

uint32_t bigEndian32(const Bytes& b, size_t at) {
  return (uint32_t{b[at]} << 24) | (uint32_t{b[at + 1]} << 16) | (uint32_t{b[at + 2]} << 8) | uint32_t{b[at + 3]};
}

std::string atByte(size_t at) { return " at byte " + std::to_string(at); }

// PNG (ISO/IEC 15948): the signature, then chunks of length (4 bytes, big-endian, < 2^31), type
// (4 letters), data and the CRC-32 of type and data, IHDR first and IEND last.
std::string pngDefect(const Bytes& b) {
  size_t at = 8;
  for (bool first = true;; first = false) {
    if (b.size() - at < 12) return "PNG cut short" + atByte(at) + ", before its IEND chunk";
    const uint32_t length = bigEndian32(b, at);
    const std::string type(b.begin() + static_cast<long>(at) + 4, b.begin() + static_cast<long>(at) + 8);
    for (const char c : type)
      if (!std::isalpha(static_cast<unsigned char>(c)))
        return "corrupt PNG: chunk" + atByte(at) + " has no valid type";
    if (length > 0x7FFFFFFFu) return "corrupt PNG: chunk " + type + atByte(at) + " has an invalid length";
    if (b.size() - at - 12 < length) return "PNG cut short in its " + type + " chunk" + atByte(at);
    const uLong crc = crc32(crc32(0L, Z_NULL, 0), b.data() + at + 4, static_cast<uInt>(length) + 4);
    if (crc != bigEndian32(b, at + 8 + length)) return "corrupt PNG: chunk " + type + atByte(at) + " fails its CRC";
    if (first && type != "IHDR") return "corrupt PNG: its first chunk is not IHDR";
    if (type == "IEND") return "";
    at += 12 + length;
  }
}

// JPEG (ITU T.81 B.1): after SOI, marker segments (0xFF, the marker, a 2-byte length that counts
// itself), each scan (SOS) followed by entropy-coded data in which 0xFF is stuffed as FF 00 and
// restart markers FF D0..D7 may stand; EOI (FF D9) ends the image. 0xFF fill bytes may precede a
// marker. What follows EOI (a camera's trailer) is not looked at.
std::string jpegDefect(const Bytes& b) {
  const size_t n = b.size();
  size_t at = 2;
  for (;;) {
    if (at >= n) return "JPEG cut short" + atByte(at) + ", before its end-of-image marker";
    if (b[at] != 0xFF) return "corrupt JPEG: no marker" + atByte(at);
    while (at < n && b[at] == 0xFF) ++at;
    if (at >= n) return "JPEG cut short" + atByte(at) + ", before its end-of-image marker";
    const unsigned marker = b[at];
    const size_t segment = at - 1;
    ++at;
    if (marker == 0xD9) return "";
    if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD7)) continue;  // no length
    if (marker == 0x00 || marker == 0xD8) return "corrupt JPEG: invalid marker" + atByte(segment);
    if (n - at < 2) return "JPEG cut short in the segment" + atByte(segment);
    const size_t length = (size_t{b[at]} << 8) | size_t{b[at + 1]};
    if (length < 2) return "corrupt JPEG: the segment" + atByte(segment) + " has an invalid length";
    if (n - at < length) return "JPEG cut short in the segment" + atByte(segment);
    at += length;
    if (marker != 0xDA) continue;
    for (;; ++at) {  // the scan's data runs to the next marker other than a restart
      if (n - at < 2) return "JPEG cut short in the scan" + atByte(segment) + ", before its end-of-image marker";
      if (b[at] == 0xFF && b[at + 1] != 0x00 && !(b[at + 1] >= 0xD0 && b[at + 1] <= 0xD7)) break;
    }
  }
}

}  // namespace

std::string imageContainerDefect(const Bytes& bytes) {
  if (isPngImage(bytes)) return pngDefect(bytes);
  if (!isJpegImage(bytes)) return "";
  const std::string defect = jpegDefect(bytes);
  return defect.empty() ? jpegScanDefect(bytes) : defect;
}

ImageRead readImageFile(const std::string& path, ImageColour colour) {
  ImageRead r;
  // Checked first, to say what is wrong with the path itself.
  std::error_code ec;
  const std::filesystem::file_status status = std::filesystem::status(path, ec);
  if (!std::filesystem::is_regular_file(status)) {
    r.problem = std::filesystem::exists(status) ? "not a regular file"
                : ec && ec != std::errc::no_such_file_or_directory ? ec.message()
                                                                    : "no such file";
    return r;
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    r.problem = "cannot be opened";
    return r;
  }
  const Bytes bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) {
    r.problem = "read error";
    return r;
  }
  if (bytes.empty()) {
    r.problem = "empty file";
    return r;
  }
  r.problem = imageContainerDefect(bytes);
  if (!r.problem.empty()) return r;
  try {
    r.image = decodeImage(bytes, colour);
  } catch (const Error& e) {
    r.problem = e.what();
  }
  return r;
}

void writePngFile(const std::string& path, const cv::Mat& image) {
  std::vector<unsigned char> png;
  try {
    png = encodePng(image);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
  writeFileAtomically(path, std::string(png.begin(), png.end()));
}

}  // namespace stereoloc
