#include "src/io/csv.h"

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <system_error>

#include "src/core/error.h"

namespace stereoloc {
namespace {

// Characters of an unexpected header an error shows.
constexpr size_t kShownHeaderChars = 80;

// Splits `line` at the commas into `out`, reusing its strings' storage (rows of a million-line
// file would otherwise allocate every field anew).
void split(const std::string& line, std::vector<std::string>* out) {
  size_t count = 0, start = 0;
  while (true) {
    const size_t comma = line.find(',', start);
    const size_t end = comma == std::string::npos ? line.size() : comma;
    if (count == out->size()) out->emplace_back();
    (*out)[count++].assign(line, start, end - start);
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  out->resize(count);
}

std::vector<std::string> split(const std::string& line) {
  std::vector<std::string> out;
  split(line, &out);
  return out;
}

std::string join(const std::vector<std::string>& v) {
  std::string s;
  for (size_t i = 0; i < v.size(); ++i) s += (i ? "," : "") + v[i];
  return s;
}

}  // namespace

char* formatDouble(double value, char* out) {
  if (value == 0.0) {  // also turns -0 into 0, so equal values print identically
    *out = '0';
    return out + 1;
  }
  // The same digits as printf("%.17g") (the standard specifies general + precision that way).
  return std::to_chars(out, out + kFormatDoubleMaxChars, value, std::chars_format::general, 17).ptr;
}

std::string formatDouble(double value) {
  char buf[kFormatDoubleMaxChars];
  return std::string(buf, formatDouble(value, buf));
}

char* formatLong(long value, char* out) { return std::to_chars(out, out + kFormatLongMaxChars, value).ptr; }

bool parseDouble(const std::string& s, double* value) {
  if (s.empty() || std::isspace(static_cast<unsigned char>(s[0]))) return false;
  const char* begin = s.data();
  const char* end = begin + s.size();
  const std::from_chars_result r = std::from_chars(begin, end, *value);
  if (r.ec == std::errc() && r.ptr == end) return true;
  // Forms from_chars does not take ('+1', hexadecimal) and under/overflow: as strtod reads them.
  char* stop = nullptr;
  errno = 0;
  *value = std::strtod(begin, &stop);
  if (stop != end) return false;
  return !(errno == ERANGE && std::fabs(*value) > 1.0);
}

CsvReader::CsvReader(const std::string& path) : path_(path), in_(path, std::ios::binary) {
  if (!in_) throw Error(path + ": cannot open");
  std::string line;
  while (std::getline(in_, line)) {
    ++line_;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (!line.empty() && line[0] == '#') continue;
    if (line.empty()) fail("empty header line");
    header_ = split(line);
    for (size_t i = 0; i < header_.size(); ++i)
      if (header_[i].empty()) fail("empty column name in the header");
    return;
  }
  throw Error(path + ":1: empty file (expected a header line)");
}

size_t CsvReader::expectHeader(const std::vector<std::vector<std::string>>& options) const {
  for (size_t i = 0; i < options.size(); ++i)
    if (header_ == options[i]) return i;
  std::string expected;
  for (size_t i = 0; i < options.size(); ++i) expected += (i ? "' or '" : "") + join(options[i]);
  // What was found, shortened: a file without line breaks (old Mac endings) is one line.
  std::string found = join(header_);
  if (found.size() > kShownHeaderChars) found = found.substr(0, kShownHeaderChars) + "...";
  for (char& c : found)
    if (c == '\r') c = ' ';
  throw Error(path_ + ":1: expected header '" + expected + "', found '" + found + "'");
}

bool CsvReader::next() {
  std::string line;
  while (std::getline(in_, line)) {
    ++line_;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) {
      // A blank line is only allowed as the last thing in the file.
      if (!pending_blank_) {
        pending_blank_ = true;
        blank_line_ = line_;
      }
      continue;
    }
    if (pending_blank_) {
      line_ = blank_line_;
      fail("empty line in the middle of the file");
    }
    if (line[0] == '#') continue;
    split(line, &fields_);
    if (fields_.size() != header_.size())
      fail("expected " + std::to_string(header_.size()) + " columns (" + join(header_) + "), found " +
           std::to_string(fields_.size()));
    return true;
  }
  fields_.clear();
  return false;
}

const std::string& CsvReader::field(size_t col) const {
  if (col >= fields_.size()) fail("internal: column " + std::to_string(col) + " out of range");
  return fields_[col];
}

double CsvReader::getDouble(size_t col) const {
  const std::string& s = field(col);
  if (s.empty()) failColumn(col, "empty field (expected a number)");
  double v = 0;
  if (!parseDouble(s, &v)) {
    char* end = nullptr;
    (void)std::strtod(s.c_str(), &end);  // only to tell the two errors apart
    if (end == s.c_str() || *end != '\0' || std::isspace(static_cast<unsigned char>(s[0])))
      failColumn(col, "'" + s + "' is not a number");
    failColumn(col, "'" + s + "' is out of range");
  }
  if (!std::isfinite(v)) failColumn(col, "'" + s + "' is not a finite number");
  return v;
}

long CsvReader::getLong(size_t col) const {
  const std::string& s = field(col);
  if (s.empty()) failColumn(col, "empty field (expected an integer)");
  {
    long v = 0;
    const std::from_chars_result r = std::from_chars(s.data(), s.data() + s.size(), v);
    if (r.ec == std::errc() && r.ptr == s.data() + s.size()) return v;
  }
  const char* begin = s.c_str();
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(begin, &end, 10);
  if (end == begin || *end != '\0' || std::isspace(static_cast<unsigned char>(s[0])))
    failColumn(col, "'" + s + "' is not an integer");
  if (errno == ERANGE) failColumn(col, "'" + s + "' is out of range");
  return v;
}

void CsvReader::fail(const std::string& reason) const {
  throw Error(path_ + ":" + std::to_string(line_) + ": " + reason);
}

void CsvReader::failColumn(size_t col, const std::string& reason) const {
  const std::string name = col < header_.size() ? header_[col] : std::to_string(col);
  fail("column '" + name + "': " + reason);
}

CsvWriter::CsvWriter(const std::vector<std::string>& header) : columns_(header.size()) {
  if (header.empty()) throw Error("CsvWriter: empty header");
  text_ = join(header) + "\n";
}

CsvWriter& CsvWriter::add(double value) {
  if (!std::isfinite(value)) throw Error("CsvWriter: refusing to write a non-finite number");
  char buf[kFormatDoubleMaxChars];
  return addField(buf, formatDouble(value, buf));
}

CsvWriter& CsvWriter::add(long value) {
  char buf[kFormatLongMaxChars];
  return addField(buf, formatLong(value, buf));
}

CsvWriter& CsvWriter::addField(const char* begin, const char* end) {
  if (in_row_ >= columns_) throw Error("CsvWriter: too many fields in a row");
  if (in_row_) text_ += ',';
  text_.append(begin, end);
  ++in_row_;
  return *this;
}

CsvWriter& CsvWriter::add(const std::string& value) {
  if (value.find_first_of(",\n\r") != std::string::npos) throw Error("CsvWriter: field contains a separator");
  if (in_row_ >= columns_) throw Error("CsvWriter: too many fields in a row");
  if (in_row_) text_ += ',';
  text_ += value;
  ++in_row_;
  return *this;
}

void CsvWriter::endRow() {
  if (in_row_ != columns_)
    throw Error("CsvWriter: row has " + std::to_string(in_row_) + " fields, expected " + std::to_string(columns_));
  text_ += '\n';
  in_row_ = 0;
  ++rows_;
}

}  // namespace stereoloc
