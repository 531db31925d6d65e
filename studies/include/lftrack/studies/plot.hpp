#pragma once
// Plots for studies, drawn by gnuplot (Debian's gnuplot-nox, installed by scripts/setup.sh):
// the data and the script are written next to the PNG, so a plot can be restyled and redrawn
// by hand. Without gnuplot the PNG is skipped with a warning and the script still written.

#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/tracking/status.hpp"

namespace lftrack::host {

struct PlotSeries {
  std::string name;
  std::vector<double> y;  // one value per x; NaN leaves a gap
};

struct LinePlot {
  std::string title, x_label, y_label;
  std::vector<double> x;
  std::vector<std::string> x_tick_labels;  // empty, or one per x: the axis names the points
  std::vector<PlotSeries> series;
  std::string key_position = "bottom left";  // gnuplot's `set key` position
  bool log_x = false;
  double y_min = 0, y_max = 0;  // equal: automatic
};

// Writes <png stem>.dat and <png stem>.gp and runs gnuplot; returns whether the PNG was drawn.
Result<bool> draw_line_plot(const LinePlot& plot, const std::filesystem::path& png);

// Points with labels; the `front` (a subset, e.g. a Pareto front) is joined by a line and
// labelled, the others are drawn unlabelled.
struct ScatterPoint {
  double x = 0, y = 0;
  std::string label;
};
struct ScatterPlot {
  std::string title, x_label, y_label;
  std::vector<ScatterPoint> points;
  std::vector<ScatterPoint> front;  // drawn in the given order
  std::string front_name = "Pareto front";
  std::string key_position = "top right";  // gnuplot's `set key` position
  bool log_x = false, log_y = false;
};

// Writes <png stem>.dat, <png stem>_front.dat and <png stem>.gp and runs gnuplot.
Result<bool> draw_scatter_plot(const ScatterPlot& plot, const std::filesystem::path& png);

}  // namespace lftrack::host
