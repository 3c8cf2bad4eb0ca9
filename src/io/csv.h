#pragma once
// A small strict CSV reader and writer for stereoloc's dataset files (and anyone else's).
//
// Format: the first line is a header of column names; every following line is one row with
// exactly as many comma-separated fields as the header. No quoting (fields never contain
// commas), surrounding spaces are not allowed inside numbers, a trailing '\r' (CRLF files) is
// accepted. Lines starting with '#' are comments and are skipped; an empty line anywhere but at
// the very end of the file is an error (a blank line is a truncated row, not "no row").
// Every error is a stereoloc::Error with the message "FILE:LINE: reason", LINE 1-based.
#include <cstdint>
#include <fstream>
#include <string>
#include <vector>

namespace stereoloc {

// %.17g: enough digits that reading the text back gives the same double (exact round trips);
// 0 and -0 print as "0". The char* form writes at most kFormatDoubleMaxChars characters to
// `out` (no terminating NUL) and returns the end: the hot path of the estimate and dataset
// writers (std::to_chars, no locale or format-string parsing).
constexpr int kFormatDoubleMaxChars = 32;
constexpr int kFormatLongMaxChars = 24;
std::string formatDouble(double value);
char* formatDouble(double value, char* out);
char* formatLong(long value, char* out);
// Reads a whole field as a double, as strtod would (also '+1', hexadecimal, inf / nan; no
// leading space); false if it is not a number or overflows. std::from_chars on the hot path.
bool parseDouble(const std::string& text, double* value);

class CsvReader {
 public:
  // Opens the file and reads its header. Throws "FILE: cannot open" or "FILE:1: empty file".
  explicit CsvReader(const std::string& path);

  const std::string& path() const { return path_; }
  const std::vector<std::string>& header() const { return header_; }
  // True when the header equals `columns` exactly.
  bool headerIs(const std::vector<std::string>& columns) const { return header_ == columns; }
  // Throws "FILE:1: expected header 'a,b,c', found 'x,y'" unless the header is one of `options`;
  // returns the index of the matching option.
  size_t expectHeader(const std::vector<std::vector<std::string>>& options) const;

  // Advances to the next data row; false at the end of the file. Throws on a wrong field count.
  bool next();
  long line() const { return line_; }  // 1-based line number of the current row
  size_t size() const { return fields_.size(); }

  // Field accessors by column index; errors name the column: "FILE:LINE: column 't': ...".
  const std::string& field(size_t col) const;
  double getDouble(size_t col) const;       // finite number (NaN / inf rejected)
  long getLong(size_t col) const;           // integer, no fraction or exponent
  [[noreturn]] void fail(const std::string& reason) const;       // "FILE:LINE: reason"
  [[noreturn]] void failColumn(size_t col, const std::string& reason) const;

 private:
  std::string path_;
  std::ifstream in_;
  std::vector<std::string> header_;
  std::vector<std::string> fields_;
  long line_ = 0;
  bool pending_blank_ = false;
  long blank_line_ = 0;
};

// Builds CSV text in memory; write it with writeFileAtomically (src/core/atomic_file.h).
class CsvWriter {
 public:
  explicit CsvWriter(const std::vector<std::string>& header);
  CsvWriter& add(double value);       // written with formatDouble
  CsvWriter& add(long value);
  CsvWriter& add(int value) { return add(static_cast<long>(value)); }
  CsvWriter& add(const std::string& value);  // must not contain ',', '\n' or '\r'
  void endRow();                      // throws if the row has the wrong number of fields
  const std::string& str() const { return text_; }
  size_t rows() const { return rows_; }

 private:
  CsvWriter& addField(const char* begin, const char* end);
  size_t columns_ = 0, in_row_ = 0, rows_ = 0;
  std::string text_;
};

}  // namespace stereoloc
