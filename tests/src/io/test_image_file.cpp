// Reading image files: sound PNGs and JPEGs decode as cv::imread decodes them (OpenCV's codecs
// are the reference here only), what encodePng writes reads back the same, and every cut-short
// or bit-flipped file is refused with its defect before a codec library sees it.
#include "src/io/image_file.h"

#include <gtest/gtest.h>
#include <zlib.h>

#include <filesystem>
#include <fstream>
#include <system_error>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "src/core/error.h"
#include "test_util.h"

namespace stereoloc {
namespace {

using Bytes = std::vector<unsigned char>;

// A small colour image with structure in it (the codecs compress it to a few hundred bytes).
cv::Mat pattern() {
  cv::Mat m(24, 32, CV_8UC3);
  for (int r = 0; r < m.rows; ++r)
    for (int c = 0; c < m.cols; ++c) m.at<cv::Vec3b>(r, c) = cv::Vec3b(r * 10, c * 8, (r * c) % 256);
  return m;
}

Bytes encode(const std::string& ext, const std::vector<int>& params = {}) {
  Bytes bytes;
  EXPECT_TRUE(cv::imencode(ext, pattern(), bytes, params));
  return bytes;
}

void writeBytes(const std::string& path, const Bytes& bytes) {
  std::ofstream(path, std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()), static_cast<long>(bytes.size()));
}

bool same(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::norm(a, b, cv::NORM_INF) == 0;
}

ImageColour colourOf(int imread_flags) {
  return imread_flags == cv::IMREAD_GRAYSCALE ? ImageColour::Grey
         : imread_flags == cv::IMREAD_COLOR   ? ImageColour::Bgr
                                              : ImageColour::AsStored;
}

TEST(ImageFile, SoundFilesDecodeAsImreadDecodesThem) {
  test::TempDir dir;
  const std::vector<std::pair<std::string, Bytes>> files = {
      {"a.png", encode(".png")},
      {"b.jpg", encode(".jpg")},
      {"c.jpg", encode(".jpg", {cv::IMWRITE_JPEG_PROGRESSIVE, 1})},
      {"d.jpg", encode(".jpg", {cv::IMWRITE_JPEG_RST_INTERVAL, 1})},  // restart markers in the scan
      {"e.png", encodePng(pattern())}};
  for (const auto& [name, bytes] : files) {
    writeBytes(dir.file(name), bytes);
    EXPECT_EQ(imageContainerDefect(bytes), "") << name;
    for (const int flags : {cv::IMREAD_UNCHANGED, cv::IMREAD_GRAYSCALE, cv::IMREAD_COLOR}) {
      const ImageRead r = readImageFile(dir.file(name), colourOf(flags));
      EXPECT_EQ(r.problem, "") << name;
      EXPECT_TRUE(same(r.image, cv::imread(dir.file(name), flags))) << name << " flags " << flags;
    }
  }
  // What follows a JPEG's end-of-image marker (a camera's trailer) is not the image's concern.
  Bytes trailer = encode(".jpg");
  trailer.insert(trailer.end(), {'E', 'X', 'T', 'R', 'A', 0xFF, 0xD8});
  EXPECT_EQ(imageContainerDefect(trailer), "");
}

// The photographs under data/ (the real field images, OpenCV's checkerboard samples).
TEST(ImageFile, EveryPhotographUnderDataPassesTheCheck) {
  size_t checked = 0;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(STEREOLOC_DATA_DIR)) {
    const std::string ext = entry.path().extension().string();
    if (ext != ".png" && ext != ".jpg") continue;
    const std::string path = entry.path().string();
    for (const int flags : {cv::IMREAD_UNCHANGED, cv::IMREAD_GRAYSCALE}) {
      const ImageRead r = readImageFile(path, colourOf(flags));
      EXPECT_EQ(r.problem, "") << path;
      EXPECT_TRUE(same(r.image, cv::imread(path, flags | cv::IMREAD_IGNORE_ORIENTATION))) << path;
    }
    ++checked;
  }
  EXPECT_GE(checked, 90u);  // 64 field photographs, 26 checkerboard views
}

TEST(ImageFile, EveryCutShortPngOrJpegIsRefused) {
  for (const std::string ext : {".png", ".jpg"}) {
    const Bytes whole = encode(ext);
    for (size_t n = 1; n < whole.size(); ++n) {
      const Bytes cut(whole.begin(), whole.begin() + static_cast<long>(n));
      const std::string defect = imageContainerDefect(cut);
      // Shorter than a signature, the bytes are no PNG or JPEG at all: the decoder refuses them.
      if (n < (ext == ".png" ? 8u : 3u)) {
        EXPECT_THROW(decodeImage(cut, ImageColour::AsStored), Error) << ext << " " << n;
        continue;
      }
      EXPECT_NE(defect.find("cut short"), std::string::npos) << ext << " cut to " << n << " bytes: '" << defect << "'";
    }
  }
}

TEST(ImageFile, EveryBitFlipInAPngIsRefused) {
  const Bytes whole = encode(".png");
  for (size_t at = 8; at < whole.size(); ++at)
    for (int bit = 0; bit < 8; ++bit) {
      Bytes flipped = whole;
      flipped[at] ^= static_cast<unsigned char>(1 << bit);
      EXPECT_NE(imageContainerDefect(flipped), "") << "byte " << at << " bit " << bit;
    }
  Bytes data_flip = whole;
  data_flip[whole.size() - 20] ^= 0x10;  // the IDAT chunk's last data byte (IEND and IDAT's CRC follow)
  EXPECT_EQ(imageContainerDefect(data_flip), "corrupt PNG: chunk IDAT at byte 33 fails its CRC");
}

TEST(ImageFile, ProblemsAreNamed) {
  test::TempDir dir;
  EXPECT_EQ(readImageFile(dir.file("absent.png"), ImageColour::AsStored).problem, "no such file");
  writeBytes(dir.file("empty.png"), {});
  EXPECT_EQ(readImageFile(dir.file("empty.png"), ImageColour::AsStored).problem, "empty file");
  writeBytes(dir.file("text.png"), {'n', 'o', 't', ' ', 'a', 'n', ' ', 'i', 'm', 'a', 'g', 'e'});
  EXPECT_EQ(readImageFile(dir.file("text.png"), ImageColour::AsStored).problem, "not a PNG or JPEG image");
  writeBytes(dir.file("e.bmp"), encode(".bmp"));
  EXPECT_EQ(readImageFile(dir.file("e.bmp"), ImageColour::Bgr).problem, "not a PNG or JPEG image");
  EXPECT_EQ(readImageFile(dir.path(), ImageColour::AsStored).problem, "not a regular file");
  std::filesystem::create_symlink("loop.png", dir.file("loop.png"));  // a link to itself
  EXPECT_EQ(readImageFile(dir.file("loop.png"), ImageColour::AsStored).problem,
            std::make_error_code(std::errc::too_many_symbolic_link_levels).message());

  // A well-formed PNG whose header declares 60000 x 60000 pixels: more than is decoded.
  Bytes huge = encode(".png");
  for (int k = 0; k < 2; ++k)  // IHDR's width and height, big-endian, at bytes 16 and 20
    for (int b = 0; b < 4; ++b)
      huge[static_cast<size_t>(16 + 4 * k + b)] = static_cast<unsigned char>((60000u >> (24 - 8 * b)) & 0xff);
  const uLong crc = crc32(crc32(0L, Z_NULL, 0), huge.data() + 12, 17);  // over IHDR's type and data
  for (int b = 0; b < 4; ++b)
    huge[static_cast<size_t>(29 + b)] = static_cast<unsigned char>((crc >> (24 - 8 * b)) & 0xff);
  ASSERT_EQ(imageContainerDefect(huge), "");
  writeBytes(dir.file("huge.png"), huge);
  const std::string huge_problem = readImageFile(dir.file("huge.png"), ImageColour::AsStored).problem;
  EXPECT_EQ(huge_problem, "PNG: larger than 2^28 pixels");

  const Bytes png = encode(".png");
  const Bytes half(png.begin(), png.begin() + static_cast<long>(png.size() / 2));
  writeBytes(dir.file("half.png"), half);
  const ImageRead r = readImageFile(dir.file("half.png"), ImageColour::AsStored);
  EXPECT_TRUE(r.image.empty());
  EXPECT_EQ(r.problem, "PNG cut short in its IDAT chunk at byte 33");
  // The decoder alone, without the container check, refuses it as well (libpng's error path).
  EXPECT_EQ(test::errorOf([&] { decodeImage(half, ImageColour::AsStored); }), "PNG: cut short");

  const Bytes jpg = encode(".jpg");
  const Bytes jpg_half(jpg.begin(), jpg.begin() + static_cast<long>(jpg.size() - 10));
  EXPECT_NE(imageContainerDefect(jpg_half).find("JPEG cut short in the scan at byte"), std::string::npos)
      << imageContainerDefect(jpg_half);
  EXPECT_EQ(test::errorOf([&] { decodeImage(jpg_half, ImageColour::Bgr); }).rfind("JPEG: ", 0), 0u);
  Bytes junk = jpg;
  const size_t after_app0 = 4 + ((size_t{jpg[4]} << 8) | jpg[5]);  // SOI, then the APP0 segment
  junk.insert(junk.begin() + static_cast<long>(after_app0), 'x');   // a byte where a marker must stand
  EXPECT_EQ(imageContainerDefect(junk), "corrupt JPEG: no marker at byte " + std::to_string(after_app0));
}

// Damage a JPEG's structure cannot show (its scan has no checksum) but libjpeg finds as it
// decodes: refused with libjpeg's words, where OpenCV would print them and return the image.
TEST(ImageFile, ScanDataLibjpegFindsCorruptIsRefused) {
  const Bytes jpg = encode(".jpg");
  size_t scan = 0;
  while (!(jpg[scan] == 0xFF && jpg[scan + 1] == 0xDA)) ++scan;
  const size_t data = scan + 2 + ((size_t{jpg[scan + 2]} << 8) | jpg[scan + 3]);
  Bytes early(jpg.begin(), jpg.begin() + static_cast<long>((data + jpg.size()) / 2));  // a frame cut off ...
  early.insert(early.end(), {0xFF, 0xD9});                                             // ... but ended
  EXPECT_EQ(imageContainerDefect(early), "corrupt JPEG: premature end of data segment");
  Bytes restart = jpg;
  restart.insert(restart.begin() + static_cast<long>(data + 40), {0xFF, 0xD3});  // a restart marker out of place
  EXPECT_NE(imageContainerDefect(restart).find("corrupt JPEG: "), std::string::npos) << imageContainerDefect(restart);
}

// What encodePng writes reads back exactly, as stored, for every kind of image it takes; and
// OpenCV reads it the same.
TEST(ImageFile, PngsWrittenReadBackExactly) {
  cv::Mat grey, bgra, deep;
  cv::cvtColor(pattern(), grey, cv::COLOR_BGR2GRAY);
  cv::cvtColor(pattern(), bgra, cv::COLOR_BGR2BGRA);
  bgra.at<cv::Vec4b>(3, 5)[3] = 17;
  pattern().convertTo(deep, CV_16UC3, 257.0);
  deep.at<cv::Vec3w>(2, 2) = cv::Vec3w(1, 40000, 65535);
  for (const cv::Mat& m : {pattern(), grey, bgra, deep}) {
    const Bytes png = encodePng(m);
    EXPECT_TRUE(same(decodeImage(png, ImageColour::AsStored), m)) << m.type();
    EXPECT_TRUE(same(decodeImage(png, ImageColour::AsStored), cv::imdecode(png, cv::IMREAD_UNCHANGED))) << m.type();
    for (const int flags : {cv::IMREAD_GRAYSCALE, cv::IMREAD_COLOR})
      EXPECT_TRUE(same(decodeImage(png, colourOf(flags)), cv::imdecode(png, flags))) << m.type() << " " << flags;
  }
  EXPECT_THROW(encodePng(cv::Mat(4, 4, CV_32FC1)), Error);
  EXPECT_THROW(encodePng(cv::Mat(4, 4, CV_8UC2)), Error);
  EXPECT_THROW(encodePng(cv::Mat()), Error);
  test::TempDir dir;
  EXPECT_THROW(writePngFile(dir.file("f.png"), cv::Mat(4, 4, CV_32FC1)), Error);
  EXPECT_FALSE(std::filesystem::exists(dir.file("f.png")));
}

}  // namespace
}  // namespace stereoloc
