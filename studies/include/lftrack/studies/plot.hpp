#pragma once
// Plots for studies, drawn by gnuplot (Debian's gnuplot-nox, installed by scripts/setup.sh):
// the data and the script are written next to the PNG, so a plot can be restyled and redrawn
// by hand. Without gnuplot the PNG is skipped with a warning and the script still written.

#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/tracking/status.hpp"

namespace lftrack::studies {

struct PlotSeries {
  std::string name;
  std::vector<double> y;     // one value per x; NaN: no point there (a line runs on to the next)
  bool points_only = false;  // points without a line (samples among a line's points)
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

// Bars in groups, as categorical results are published: one group per category (a method, a
// factor), one bar per series in each group, each bar with its error bar (low, high; equal to the
// value: none). The categories name the axis (put the count n in them).
struct BarSeries {
  std::string name;
  std::vector<double> value, low, high;  // one per category
};
struct GroupedBarChart {
  std::string title, y_label;
  std::vector<std::string> categories;
  std::vector<BarSeries> series;
  double y_min = 0, y_max = 0;  // equal: automatic
  std::string key_position = "top right";
  int width = 1100;                 // pixels; many categories want more
  bool slanted_categories = false;  // category names slanted (long names, many categories)
};
// Writes <png stem>.dat and <png stem>.gp and runs gnuplot.
Result<bool> draw_grouped_bars(const GroupedBarChart& chart, const std::filesystem::path& png);

// The 95 % Wilson score interval of a proportion: `successes` of `n` (n = 0: [0, 1]).
std::pair<double, double> wilson_interval(int successes, int n);

// Points in named groups (a colour and a key entry each), with reference lines across the plot
// (thresholds): vertical at x = `at`, or horizontal at y = `at`.
struct PointGroup {
  std::string name;
  std::vector<double> x, y;  // one point per pair; non-finite pairs are left out
};
struct ReferenceLine {
  bool vertical = true;
  double at = 0;
  std::string name;
  bool dashed = false;
};
struct GroupedScatterPlot {
  std::string title, x_label, y_label;
  std::vector<PointGroup> groups;
  std::vector<ReferenceLine> lines;
  std::string key_position = "bottom right";
};

// Writes <png stem>.dat (one block per group) and <png stem>.gp and runs gnuplot.
Result<bool> draw_grouped_scatter(const GroupedScatterPlot& plot, const std::filesystem::path& png);

}  // namespace lftrack::studies
