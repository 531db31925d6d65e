#pragma once
// The studies' CSV cells: numbers written so they read back exactly, and lines split at commas
// (no quoting: study files hold no commas inside a cell).

#include <cmath>
#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

namespace lftrack::studies {

// 9 significant digits (a double's value to the digit a float keeps); "nan", "inf", "-inf".
inline std::string csv_number(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}

// The cells of one line; a trailing comma gives a last, empty cell.
inline std::vector<std::string> split_csv_line(const std::string& line) {
  std::vector<std::string> cells;
  std::stringstream in(line);
  std::string cell;
  while (std::getline(in, cell, ',')) cells.push_back(cell);
  if (!line.empty() && line.back() == ',') cells.emplace_back();
  return cells;
}

}  // namespace lftrack::studies
