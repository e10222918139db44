#include "core/eval/ground_truth.h"

#include <cstdio>
#include <sstream>

namespace uavm::eval {

std::string FormatGroundTruthCsv(const std::vector<GtRow>& rows) {
  std::string out = std::string(kGroundTruthHeader) + "\n";
  char buf[1024];
  for (const auto& r : rows) {
    const Mat3 c = r.canvas_from_frame / r.canvas_from_frame(2, 2);
    const Mat3& a = r.affine;
    // %.17g: the evaluator's known-answer tests go down to 1e-6 px, so no rounding here.
    std::snprintf(buf, sizeof(buf),
                  "%d,%s,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g\n",
                  r.index, r.filename.c_str(), c(0, 0), c(0, 1), c(0, 2), c(1, 0), c(1, 1), c(1, 2), c(2, 0), c(2, 1),
                  c(2, 2), a(0, 0), a(0, 1), a(0, 2), a(1, 0), a(1, 1), a(1, 2));
    out += buf;
  }
  return out;
}

namespace {

std::vector<std::string> SplitComma(const std::string& line) {
  std::vector<std::string> out;
  std::string cur;
  for (char ch : line) {
    if (ch == ',') {
      out.push_back(cur);
      cur.clear();
    } else if (ch != '\r') {
      cur += ch;
    }
  }
  out.push_back(cur);
  return out;
}

bool ToDouble(const std::string& s, double* v) {
  if (s.empty()) return false;
  char* end = nullptr;
  *v = std::strtod(s.c_str(), &end);
  return end != nullptr && *end == '\0';
}

}  // namespace

bool ParseGroundTruthCsv(const std::string& text, std::vector<GtRow>* rows, std::string* error) {
  rows->clear();
  std::istringstream in(text);
  std::string line;
  if (!std::getline(in, line)) {
    *error = "gt.csv is empty";
    return false;
  }
  if (!line.empty() && line.back() == '\r') line.pop_back();
  if (line != kGroundTruthHeader) {
    *error = "gt.csv: unexpected header '" + line + "'";
    return false;
  }
  int line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.empty() || line == "\r") continue;
    const auto f = SplitComma(line);
    if (f.size() != 17) {
      *error = "gt.csv line " + std::to_string(line_no) + ": expected 17 fields, got " + std::to_string(f.size());
      return false;
    }
    GtRow r;
    double v[15];
    double idx = 0;
    bool ok = ToDouble(f[0], &idx);
    for (int i = 0; i < 15 && ok; ++i) ok = ToDouble(f[static_cast<size_t>(i) + 2], &v[i]);
    if (!ok) {
      *error = "gt.csv line " + std::to_string(line_no) + ": malformed number";
      return false;
    }
    r.index = static_cast<int>(idx);
    r.filename = f[1];
    r.canvas_from_frame << v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8];
    r.affine << v[9], v[10], v[11], v[12], v[13], v[14], 0, 0, 1;
    rows->push_back(std::move(r));
  }
  return true;
}

}  // namespace uavm::eval
