#include "lftrack/studies/plot.hpp"

#include <spdlog/spdlog.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>

namespace lftrack::studies {

namespace {
std::string quoted(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}
std::string gp_string(const std::string& s) {
  std::string out = "\"";
  for (char c : s) out += (c == '"' || c == '\\') ? std::string("\\") + c : std::string(1, c);
  return out + "\"";
}

// A script's first lines: a PNG of `width` x `height` pixels at `png` (beside the script), titled.
std::string gp_preamble(int width, int height, const std::filesystem::path& png, const std::string& title,
                        bool enhanced_title) {
  return "set terminal pngcairo size " + std::to_string(width) + "," + std::to_string(height) +
         " enhanced font 'DejaVu Sans,11'\nset output " + gp_string(png.filename().string()) + "\nset title " +
         gp_string(title) + (enhanced_title ? "" : " noenhanced") + "\n";
}

// Runs gnuplot on `gp` in its folder; false (with a warning) where gnuplot is not installed.
Result<bool> run_gnuplot(const std::filesystem::path& gp) {
  if (std::system("command -v gnuplot >/dev/null 2>&1") != 0) {
    spdlog::warn("gnuplot not found (scripts/setup.sh installs it); wrote {} without drawing it",
                 gp.string());
    return false;
  }
  const std::string command = "cd " + quoted(gp.parent_path().empty() ? "." : gp.parent_path().string()) +
                              " && gnuplot " + quoted(gp.filename().string()) + " 2>&1";
  if (std::system(command.c_str()) != 0) return io_error("gnuplot failed on " + gp.string());
  // gnuplot exits 0 on an empty script and on a PNG it could not finish (a full disk).
  std::error_code ec;
  const auto png = std::filesystem::path(gp).replace_extension(".png");
  if (!std::filesystem::exists(png, ec) || std::filesystem::file_size(png, ec) == 0 || ec)
    return io_error(png.string() + ": gnuplot wrote no image (disk full?)");
  return true;
}

}  // namespace

Result<bool> draw_line_plot(const LinePlot& plot, const std::filesystem::path& png) {
  const auto dat = std::filesystem::path(png).replace_extension(".dat");
  const auto gp = std::filesystem::path(png).replace_extension(".gp");
  {
    std::ofstream d(dat);
    if (!d) return io_error(dat.string() + ": cannot write");
    d << "# x";
    for (const auto& s : plot.series) d << '\t' << s.name;
    d << '\n';
    for (std::size_t i = 0; i < plot.x.size(); ++i) {
      d << plot.x[i];
      for (const auto& s : plot.series) {
        const double y = i < s.y.size() ? s.y[i] : NAN;
        if (std::isfinite(y))
          d << '\t' << y;
        else
          d << "\tNaN";
      }
      d << '\n';
    }
    d.flush();
    if (!d) return io_error(dat.string() + ": write failed (disk full?)");
  }
  {
    std::ofstream g(gp);
    if (!g) return io_error(gp.string() + ": cannot write");
    g << gp_preamble(900, 600, png, plot.title, true)
      << "set xlabel " << gp_string(plot.x_label) << "\nset ylabel " << gp_string(plot.y_label) << "\n"
      << "set grid\nset key " << plot.key_position << " box opaque\nset datafile missing 'NaN'\n";
    if (plot.log_x) g << "set logscale x\n";
    if (plot.y_max > plot.y_min) g << "set yrange [" << plot.y_min << ":" << plot.y_max << "]\n";
    if (!plot.x_tick_labels.empty() && plot.x_tick_labels.size() == plot.x.size()) {
      g << "set xtics noenhanced rotate by -25 (";
      for (std::size_t i = 0; i < plot.x.size(); ++i)
        g << (i ? ", " : "") << gp_string(plot.x_tick_labels[i]) << " " << plot.x[i];
      g << ")\nset xrange [" << plot.x.front() - 0.5 << ":" << plot.x.back() + 0.5 << "]\n";
    }
    g << "plot ";
    for (std::size_t s = 0; s < plot.series.size(); ++s) {
      g << (s ? ", \\\n     " : "") << gp_string(dat.filename().string()) << " using 1:" << s + 2
        << (plot.series[s].points_only ? " with points pt 7 ps 1.5" : " with linespoints lw 2 pt 7")
        << " title " << gp_string(plot.series[s].name);
    }
    g << "\n";
    g.flush();
    if (!g) return io_error(gp.string() + ": write failed (disk full?)");
  }
  return run_gnuplot(gp);
}

Result<bool> draw_scatter_plot(const ScatterPlot& plot, const std::filesystem::path& png) {
  const auto dat = std::filesystem::path(png).replace_extension(".dat");
  const auto front = std::filesystem::path(png).replace_extension("").string() + "_front.dat";
  const auto gp = std::filesystem::path(png).replace_extension(".gp");
  auto write_points = [](const std::filesystem::path& file,
                         const std::vector<ScatterPoint>& points) -> Status {
    std::ofstream d(file);
    if (!d) return io_error(file.string() + ": cannot write");
    d << "# x\ty\tlabel\n";
    for (const auto& p : points)
      if (std::isfinite(p.x) && std::isfinite(p.y))
        d << p.x << '\t' << p.y << '\t' << gp_string(p.label) << '\n';
    d.flush();
    if (!d) return io_error(file.string() + ": write failed (disk full?)");
    return {};
  };
  LFTRACK_RETURN_IF_ERROR(write_points(dat, plot.points));
  LFTRACK_RETURN_IF_ERROR(write_points(front, plot.front));
  {
    std::ofstream g(gp);
    if (!g) return io_error(gp.string() + ": cannot write");
    const std::string front_name = std::filesystem::path(front).filename().string();
    g << gp_preamble(1000, 700, png, plot.title, false)
      << "set xlabel " << gp_string(plot.x_label) << "\nset ylabel " << gp_string(plot.y_label) << "\n"
      << "set grid\nset key " << plot.key_position << " box opaque\n";
    if (plot.log_x) g << "set logscale x\n";
    if (plot.log_y) g << "set logscale y\n";
    g << "plot " << gp_string(dat.filename().string())
      << " using 1:2 with points pt 7 ps 1.2 lc rgb '#8090a0' title 'operating points', \\\n     "
      << gp_string(front_name) << " using 1:2 with linespoints lw 2 pt 7 ps 1.5 lc rgb '#c03020' title "
      << gp_string(plot.front_name) << ", \\\n     " << gp_string(front_name)
      << " every 2 using 1:2:3 with labels left offset 0.8,0.6 font ',9' noenhanced notitle, \\\n     "
      << gp_string(front_name)  // every other label below its point, so neighbours do not overlap
      << " every 2::1 using 1:2:3 with labels left offset 0.8,-0.9 font ',9' noenhanced notitle\n";
    g.flush();
    if (!g) return io_error(gp.string() + ": write failed (disk full?)");
  }
  return run_gnuplot(gp);
}

Result<bool> draw_grouped_scatter(const GroupedScatterPlot& plot, const std::filesystem::path& png) {
  const auto dat = std::filesystem::path(png).replace_extension(".dat");
  const auto gp = std::filesystem::path(png).replace_extension(".gp");
  {
    std::ofstream d(dat);
    if (!d) return io_error(dat.string() + ": cannot write");
    d.precision(8);
    for (const PointGroup& g : plot.groups) {  // gnuplot's `index` counts blocks two blank lines apart
      d << "# " << g.name << "\n# x\ty\n";
      bool any = false;
      for (std::size_t i = 0; i < g.x.size() && i < g.y.size(); ++i)
        if (std::isfinite(g.x[i]) && std::isfinite(g.y[i])) d << g.x[i] << '\t' << g.y[i] << '\n', any = true;
      if (!any) d << "nan\tnan\n";
      d << "\n\n";
    }
    d.flush();
    if (!d) return io_error(dat.string() + ": write failed (disk full?)");
  }
  std::ofstream g(gp);
  if (!g) return io_error(gp.string() + ": cannot write");
  g << gp_preamble(1000, 750, png, plot.title, false)
    << "set xlabel " << gp_string(plot.x_label) << " noenhanced\nset ylabel " << gp_string(plot.y_label)
    << " noenhanced\nset grid\nset key " << plot.key_position << " box opaque noenhanced\n";
  std::string parts;
  for (std::size_t i = 0; i < plot.groups.size(); ++i)
    parts += std::string(parts.empty() ? "" : ", \\\n     ") + gp_string(dat.filename().string()) + " index " +
             std::to_string(i) + " using 1:2 with points pt 7 ps 0.8 title " + gp_string(plot.groups[i].name);
  for (const ReferenceLine& line : plot.lines) {
    std::ostringstream at;
    at.precision(8);
    at << line.at;
    const std::string style = std::string(" with lines lw 2 dt ") + (line.dashed ? "2" : "1") + " lc rgb '#202020'";
    if (line.vertical) {  // a parametric-free vertical line: two points at the y range's ends
      g << "set arrow from " << at.str() << ", graph 0 to " << at.str() << ", graph 1 nohead lw 2 dt "
        << (line.dashed ? "2" : "1") << " lc rgb '#202020'\n"
        << "set label " << gp_string(line.name) << " at " << at.str() << ", graph 0.98 left offset 0.5,0 font ',9' noenhanced\n";
    } else {
      parts += ", \\\n     " + at.str() + style + " title " + gp_string(line.name);
    }
  }
  g << "plot " << parts << "\n";
  g.flush();
  if (!g) return io_error(gp.string() + ": write failed (disk full?)");
  g.close();
  return run_gnuplot(gp);
}

std::pair<double, double> wilson_interval(int successes, int n) {
  if (n <= 0) return {0.0, 1.0};
  const double z = 1.959964, p = double(successes) / n, z2n = z * z / n;
  const double centre = (p + z2n / 2) / (1 + z2n);
  const double half = z * std::sqrt(p * (1 - p) / n + z2n / (4.0 * n)) / (1 + z2n);
  return {std::max(0.0, centre - half), std::min(1.0, centre + half)};
}

Result<bool> draw_grouped_bars(const GroupedBarChart& chart, const std::filesystem::path& png) {
  const auto dat = std::filesystem::path(png).replace_extension(".dat");
  const auto gp = std::filesystem::path(png).replace_extension(".gp");
  {
    std::ofstream d(dat);
    if (!d) return io_error(dat.string() + ": cannot write");
    d.precision(8);
    d << "# category";
    for (const BarSeries& s : chart.series) d << '\t' << gp_string(s.name) << " value low high";
    d << '\n';
    for (std::size_t c = 0; c < chart.categories.size(); ++c) {
      d << gp_string(chart.categories[c]);
      for (const BarSeries& s : chart.series) {
        const auto at = [&](const std::vector<double>& v) { return c < v.size() && std::isfinite(v[c]) ? v[c] : 0.0; };
        const double value = at(s.value);
        d << '\t' << value << '\t' << (c < s.low.size() ? at(s.low) : value) << '\t'
          << (c < s.high.size() ? at(s.high) : value);
      }
      d << '\n';
    }
    d.flush();
    if (!d) return io_error(dat.string() + ": write failed (disk full?)");
  }
  std::ofstream g(gp);
  if (!g) return io_error(gp.string() + ": cannot write");
  g << gp_preamble(chart.width, 650, png, chart.title, false)
    << "set ylabel " << gp_string(chart.y_label) << " noenhanced\n"
    << "set grid ytics\nset key " << chart.key_position << " box opaque noenhanced\n"
    << "set style data histogram\nset style histogram errorbars gap 1 lw 1.5\n"
    << "set style fill solid 0.7 border -1\nset boxwidth 0.9\nset xtics noenhanced\n";
  if (chart.slanted_categories) g << "set xtics rotate by -30\nset bmargin 9\n";
  if (chart.y_max > chart.y_min) g << "set yrange [" << chart.y_min << ":" << chart.y_max << "]\n";
  else g << "set yrange [0:*]\n";
  g << "plot ";
  for (std::size_t i = 0; i < chart.series.size(); ++i) {
    const std::size_t col = 2 + 3 * i;
    g << (i ? ", \\\n     " : "") << gp_string(dat.filename().string()) << " using " << col << ':' << col + 1 << ':'
      << col + 2 << (i == 0 ? ":xtic(1)" : "") << " title " << gp_string(chart.series[i].name);
  }
  g << "\n";
  g.flush();
  if (!g) return io_error(gp.string() + ": write failed (disk full?)");
  g.close();
  return run_gnuplot(gp);
}

}  // namespace lftrack::studies
