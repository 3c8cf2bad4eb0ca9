#include "src/io/image_codec.h"

#include <cstdio>  // jpeglib.h uses FILE without including it
// clang-format off
#include <jpeglib.h>
#include <jerror.h>
// clang-format on
#include <png.h>
#include <zlib.h>

#include <csetjmp>
#include <cstring>
#include <opencv2/imgproc.hpp>

#include "src/core/error.h"

namespace stereoloc {
namespace {

using Bytes = std::vector<unsigned char>;

// Far beyond any camera's frame; keeps a forged header from asking for gigabytes.
constexpr unsigned long kMaxPixels = 1ul << 28;

// What libpng's callbacks see. Nothing in it has a destructor: libpng leaves by longjmp.
struct PngIo {
  const unsigned char* data = nullptr;
  size_t size = 0, at = 0;
  Bytes* out = nullptr;  // when writing
  char message[160] = "";
};

[[noreturn]] void onPngError(png_structp png, png_const_charp text) {
  auto* io = static_cast<PngIo*>(png_get_error_ptr(png));
  std::snprintf(io->message, sizeof io->message, "%s", text);
  png_longjmp(png, 1);
}

void onPngWarning(png_structp, png_const_charp) {}  // an unknown chunk or the like: not an error

void readPngBytes(png_structp png, png_bytep out, png_size_t n) {
  auto* io = static_cast<PngIo*>(png_get_io_ptr(png));
  if (io->size - io->at < n) png_error(png, "cut short");
  std::memcpy(out, io->data + io->at, n);
  io->at += n;
}

void writePngBytes(png_structp png, png_bytep data, png_size_t n) {
  auto* io = static_cast<PngIo*>(png_get_io_ptr(png));
  bool stored = true;
  try {
    io->out->insert(io->out->end(), data, data + n);
  } catch (...) {  // no C++ exception may cross libpng's C frames, nor a longjmp leave a handler
    stored = false;
  }
  if (!stored) png_error(png, "out of memory");
}

void flushPng(png_structp) {}

// Reads the PNG into *image with libpng's expansions for `colour` (palettes and low bit depths to
// 8 bits, BGR order; 16 bits kept, in the host's order, only as stored); the caller converts
// what libpng's transformations leave (an alpha channel, a grey image wanted as colour). *rows
// holds the row pointers. Only locals without destructors live across the setjmp.
bool readPng(PngIo* io, ImageColour colour, cv::Mat* image, std::vector<png_bytep>* rows) {
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, io, onPngError, onPngWarning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    std::snprintf(io->message, sizeof io->message, "out of memory");
    return false;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_read_struct(&png, &info, nullptr);
    return false;
  }
  png_set_read_fn(png, io, readPngBytes);
  png_read_info(png, info);
  const png_uint_32 width = png_get_image_width(png, info), height = png_get_image_height(png, info);
  const int type = png_get_color_type(png, info), bit_depth = png_get_bit_depth(png, info);
  if (static_cast<unsigned long>(width) * height > kMaxPixels) png_error(png, "larger than 2^28 pixels");
  if (type == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(png);
  if (type == PNG_COLOR_TYPE_GRAY && bit_depth < 8) png_set_expand_gray_1_2_4_to_8(png);
  if (colour == ImageColour::AsStored) {
    if (png_get_valid(png, info, PNG_INFO_tRNS)) png_set_tRNS_to_alpha(png);
    const bool grey_alpha = type == PNG_COLOR_TYPE_GRAY_ALPHA || (type == PNG_COLOR_TYPE_GRAY && png_get_valid(png, info, PNG_INFO_tRNS));
    if (grey_alpha) png_set_gray_to_rgb(png);  // grey with alpha as BGRA
    if (bit_depth == 16) png_set_swap(png);
  } else {
    png_set_strip_alpha(png);
    if (bit_depth == 16) png_set_strip_16(png);
  }
  // A colour image wanted grey: libpng's luma with OpenCV's weights (what cv::imread gives).
  const bool to_grey = colour == ImageColour::Grey && (type & PNG_COLOR_MASK_COLOR);
  if (to_grey)
    png_set_rgb_to_gray(png, 1, 0.299, 0.587);
  else
    png_set_bgr(png);
  png_set_interlace_handling(png);
  png_read_update_info(png, info);
  const int channels = png_get_channels(png, info);
  const int depth = png_get_bit_depth(png, info) == 16 ? CV_16U : CV_8U;
  image->create(static_cast<int>(height), static_cast<int>(width), CV_MAKETYPE(depth, channels));
  rows->resize(height);
  for (png_uint_32 r = 0; r < height; ++r) (*rows)[r] = image->ptr(static_cast<int>(r));
  png_read_image(png, rows->data());
  png_read_end(png, nullptr);
  png_destroy_read_struct(&png, &info, nullptr);
  return true;
}

bool writePng(PngIo* io, const cv::Mat& image, std::vector<png_bytep>* rows) {
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, io, onPngError, onPngWarning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info) {
    png_destroy_write_struct(&png, nullptr);
    std::snprintf(io->message, sizeof io->message, "out of memory");
    return false;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return false;
  }
  png_set_write_fn(png, io, writePngBytes, flushPng);
  // Speed over size, as OpenCV's own PNG writer: the renderer writes two images per step.
  png_set_compression_level(png, 1);
  png_set_compression_strategy(png, Z_RLE);
  png_set_filter(png, PNG_FILTER_TYPE_BASE, PNG_FILTER_SUB);
  const int channels = image.channels();
  const int type = channels == 1 ? PNG_COLOR_TYPE_GRAY : channels == 3 ? PNG_COLOR_TYPE_RGB : PNG_COLOR_TYPE_RGB_ALPHA;
  png_set_IHDR(png, info, static_cast<png_uint_32>(image.cols), static_cast<png_uint_32>(image.rows),
               image.depth() == CV_16U ? 16 : 8, type, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  if (channels > 1) png_set_bgr(png);
  if (image.depth() == CV_16U) png_set_swap(png);
  png_write_image(png, rows->data());
  png_write_end(png, info);
  png_destroy_write_struct(&png, &info);
  return true;
}

cv::Mat decodePng(const Bytes& bytes, ImageColour colour) {
  PngIo io;
  io.data = bytes.data();
  io.size = bytes.size();
  cv::Mat image;
  std::vector<png_bytep> rows;
  if (!readPng(&io, colour, &image, &rows)) throw Error(std::string("PNG: ") + io.message);
  return image;
}

// libjpeg's error manager, made to stop at an error and at a warning that means corrupt data
// (it would otherwise print the warning and decode the rest as grey or garbage).
struct JpegErrors {
  jpeg_error_mgr manager;  // first: libjpeg hands back a pointer to it
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX];
};

[[noreturn]] void stopJpeg(j_common_ptr cinfo) {
  auto* errors = reinterpret_cast<JpegErrors*>(cinfo->err);
  (*cinfo->err->format_message)(cinfo, errors->message);
  std::longjmp(errors->jump, 1);
}

void onJpegMessage(j_common_ptr cinfo, int level) {
  if (level >= 0) return;  // trace messages
  switch (cinfo->err->msg_code) {
    case JWRN_ARITH_BAD_CODE: case JWRN_BOGUS_PROGRESSION: case JWRN_EXTRANEOUS_DATA: case JWRN_HIT_MARKER:
    case JWRN_HUFF_BAD_CODE: case JWRN_JPEG_EOF: case JWRN_MUST_RESYNC:
      stopJpeg(cinfo);
    default:  // a harmless oddity (an unknown JFIF revision, a bad ICC profile): not corrupt pixels
      return;
  }
}

void installJpegErrors(jpeg_decompress_struct* cinfo, JpegErrors* errors) {
  cinfo->err = jpeg_std_error(&errors->manager);
  errors->manager.error_exit = stopJpeg;
  errors->manager.emit_message = onJpegMessage;
  errors->message[0] = '\0';
}

// libjpeg's text without its "Corrupt JPEG data: " prefix.
std::string jpegMessage(const JpegErrors& errors) {
  const char* text = errors.message;
  static const char kPrefix[] = "Corrupt JPEG data: ";
  if (std::strncmp(text, kPrefix, sizeof kPrefix - 1) == 0) text += sizeof kPrefix - 1;
  return text;
}

// Decodes the JPEG into *image: grey as grey, colour as BGR or, for ImageColour::Grey, as its
// luma (libjpeg's Y channel). Only locals without destructors live across the setjmp.
bool readJpeg(const Bytes& bytes, ImageColour colour, JpegErrors* errors, cv::Mat* image) {
  jpeg_decompress_struct cinfo;
  installJpegErrors(&cinfo, errors);
  if (setjmp(errors->jump)) {
    jpeg_destroy_decompress(&cinfo);
    return false;
  }
  jpeg_create_decompress(&cinfo);
  jpeg_mem_src(&cinfo, bytes.data(), static_cast<unsigned long>(bytes.size()));
  jpeg_read_header(&cinfo, TRUE);
  if (cinfo.jpeg_color_space == JCS_CMYK || cinfo.jpeg_color_space == JCS_YCCK) {
    std::snprintf(errors->message, sizeof errors->message, "CMYK images are not read");
    jpeg_destroy_decompress(&cinfo);
    return false;
  }
  const bool grey = colour == ImageColour::Grey || cinfo.jpeg_color_space == JCS_GRAYSCALE;
  cinfo.out_color_space = grey ? JCS_GRAYSCALE : JCS_EXT_BGR;
  jpeg_start_decompress(&cinfo);
  if (static_cast<unsigned long>(cinfo.output_width) * cinfo.output_height > kMaxPixels) {
    std::snprintf(errors->message, sizeof errors->message, "larger than 2^28 pixels");
    jpeg_destroy_decompress(&cinfo);
    return false;
  }
  image->create(static_cast<int>(cinfo.output_height), static_cast<int>(cinfo.output_width),
                CV_8UC(cinfo.output_components));
  while (cinfo.output_scanline < cinfo.output_height) {
    JSAMPROW row = image->ptr(static_cast<int>(cinfo.output_scanline));
    jpeg_read_scanlines(&cinfo, &row, 1);
  }
  jpeg_finish_decompress(&cinfo);
  jpeg_destroy_decompress(&cinfo);
  return true;
}

cv::Mat decodeJpeg(const Bytes& bytes, ImageColour colour) {
  JpegErrors errors;
  cv::Mat image;
  if (!readJpeg(bytes, colour, &errors, &image)) throw Error("JPEG: " + jpegMessage(errors));
  return image;
}

}  // namespace

bool isPngImage(const Bytes& b) {
  static const unsigned char kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  return b.size() >= 8 && std::memcmp(b.data(), kSignature, 8) == 0;
}

bool isJpegImage(const Bytes& b) { return b.size() >= 3 && b[0] == 0xFF && b[1] == 0xD8 && b[2] == 0xFF; }

cv::Mat decodeImage(const Bytes& bytes, ImageColour colour) {
  cv::Mat image;
  if (isPngImage(bytes))
    image = decodePng(bytes, colour);
  else if (isJpegImage(bytes))
    image = decodeJpeg(bytes, colour);
  else
    throw Error("not a PNG or JPEG image");
  // The decoders give grey already when asked for it; a grey image asked for as colour is repeated.
  if (colour == ImageColour::Bgr && image.channels() == 1) cv::cvtColor(image, image, cv::COLOR_GRAY2BGR);
  return image;
}

Bytes encodePng(const cv::Mat& image) {
  const int channels = image.channels();
  if (image.empty() || (image.depth() != CV_8U && image.depth() != CV_16U) ||
      (channels != 1 && channels != 3 && channels != 4))
    throw Error("PNG: only 8- or 16-bit images of 1, 3 or 4 channels are written");
  std::vector<png_bytep> rows(static_cast<size_t>(image.rows));
  for (int r = 0; r < image.rows; ++r) rows[static_cast<size_t>(r)] = const_cast<png_bytep>(image.ptr(r));
  Bytes out;
  out.reserve(image.total() * image.elemSize() / 2 + 1024);
  PngIo io;
  io.out = &out;
  if (!writePng(&io, image, &rows)) throw Error(std::string("PNG: ") + io.message);
  return out;
}

std::string jpegScanDefect(const Bytes& b) {
  jpeg_decompress_struct cinfo;
  JpegErrors errors;
  installJpegErrors(&cinfo, &errors);
  if (setjmp(errors.jump)) {
    jpeg_destroy_decompress(&cinfo);
    return "corrupt JPEG: " + jpegMessage(errors);
  }
  jpeg_create_decompress(&cinfo);
  jpeg_mem_src(&cinfo, b.data(), static_cast<unsigned long>(b.size()));
  jpeg_read_header(&cinfo, TRUE);
  cinfo.scale_num = 1;
  cinfo.scale_denom = 8;
  cinfo.dct_method = JDCT_IFAST;
  cinfo.do_fancy_upsampling = FALSE;
  jpeg_start_decompress(&cinfo);
  const JDIMENSION row_samples = cinfo.output_width * static_cast<JDIMENSION>(cinfo.output_components);
  JSAMPARRAY row = (*cinfo.mem->alloc_sarray)(reinterpret_cast<j_common_ptr>(&cinfo), JPOOL_IMAGE, row_samples, 1);
  while (cinfo.output_scanline < cinfo.output_height) jpeg_read_scanlines(&cinfo, row, 1);
  jpeg_finish_decompress(&cinfo);
  jpeg_destroy_decompress(&cinfo);
  return "";
}

}  // namespace stereoloc
