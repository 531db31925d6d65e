#include "lftrack/studies/plastimatch_peer.hpp"

#include "lftrack/tracking/image_io.hpp"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

extern char** environ;

namespace lftrack::studies {
namespace {

namespace fs = std::filesystem;

std::string triple(const Eigen::Vector3d& v) {
  std::ostringstream s;
  s.precision(12);
  s << v.x() << ' ' << v.y() << ' ' << v.z();
  return s.str();
}

std::string number(double a) {
  std::ostringstream s;
  s.precision(12);
  s << a;
  return s.str();
}

std::string pair(double a, double b) {
  return number(a) + ' ' + number(b);
}

// plastimatch writes PFM with row 0 first, where the format stores the bottom row first: read
// it as a standard PFM, then flip it back and convert cm to mm.
Result<tracking::Image<float>> read_plastimatch_pfm(const fs::path& file) {
  auto pfm = tracking::read_pfm(file);
  if (!pfm.ok()) return pfm.status().with_context("plastimatch output");
  const tracking::Image<float>& bottom_up = *pfm;
  tracking::Image<float> image(bottom_up.rows(), bottom_up.cols());
  for (int r = 0; r < image.rows(); ++r)
    for (int c = 0; c < image.cols(); ++c) image.at(r, c) = 10.0f * bottom_up.at(image.rows() - 1 - r, c);
  return image;
}

}  // namespace

Status run_process(const std::vector<std::string>& argv, std::string* output,
                   const std::vector<std::string>& extra_env) {
  char log_template[] = "/tmp/lftrack-process-XXXXXX";
  const int log_fd = mkstemp(log_template);
  if (log_fd < 0) return io_error("cannot create a temporary file for process output");
  unlink(log_template);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, log_fd, STDOUT_FILENO);
  posix_spawn_file_actions_adddup2(&actions, log_fd, STDERR_FILENO);
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  pid_t pid = 0;
  std::vector<char*> env;
  for (char** e = environ; *e; ++e) env.push_back(*e);
  for (const auto& e : extra_env) env.push_back(const_cast<char*>(e.c_str()));
  env.push_back(nullptr);
  const int spawn_error = posix_spawnp(&pid, args[0], &actions, nullptr, args.data(), env.data());
  posix_spawn_file_actions_destroy(&actions);
  if (spawn_error != 0) {
    close(log_fd);
    return not_found(argv[0] + ": cannot start (" + std::strerror(spawn_error) + ")");
  }
  int wstatus = 0;
  while (waitpid(pid, &wstatus, 0) < 0 && errno == EINTR) {
  }
  if (output) {
    output->clear();
    lseek(log_fd, 0, SEEK_SET);
    char buffer[4096];
    ssize_t n;
    while ((n = read(log_fd, buffer, sizeof buffer)) > 0) output->append(buffer, static_cast<std::size_t>(n));
  }
  close(log_fd);
  if (!WIFEXITED(wstatus) || WEXITSTATUS(wstatus) != 0) {
    return internal_error(argv[0] + " failed (status " + std::to_string(wstatus) + ")");
  }
  return {};
}

bool plastimatch_available() {
  std::string out;
  return run_process({"plastimatch", "--version"}, &out).ok();
}

Result<std::vector<std::string>> plastimatch_drr_arguments(const tracking::XrayView& v,
                                                           const fs::path& volume_mha,
                                                           const std::string& output_prefix) {
  LFTRACK_RETURN_IF_ERROR(v.validate());
  const Eigen::Vector3d nrm = v.detector_normal();
  if (v.col_axis.cross(v.row_axis).dot(nrm) > 0) {
    return unsupported("view '" + v.name +
                       "' is mirrored relative to plastimatch's detector (col x row points at the source)");
  }
  const double sid = v.source_to_detector_mm();
  const double sad = 0.5 * sid;
  const Eigen::Vector3d isocentre = v.source_mm - sad * nrm;
  const auto principal = v.project(v.principal_point_mm());
  if (!principal) return internal_error("principal point does not project");
  return std::vector<std::string>{"plastimatch",
                                  "drr",
                                  "-P",
                                  "none",
                                  "-i",
                                  "exact",
                                  "-t",
                                  "pfm",
                                  "--nrm",
                                  triple(nrm),
                                  "--vup",
                                  triple(-v.row_axis),
                                  "--sad",
                                  number(sad),
                                  "--sid",
                                  number(sid),
                                  "-o",
                                  triple(isocentre),
                                  "-r",
                                  std::to_string(v.cols) + " " + std::to_string(v.rows),
                                  "-z",
                                  pair(v.cols * v.pitch_col_mm, v.rows * v.pitch_row_mm),
                                  "-c",
                                  pair(principal->x(), principal->y()),
                                  "-O",
                                  output_prefix,
                                  volume_mha.string()};
}

Result<PeerDrr> run_plastimatch_drr(const tracking::XrayView& view_ct, const fs::path& volume_mha,
                                    const fs::path& work_dir, int threads) {
  std::error_code ec;
  fs::create_directories(work_dir, ec);
  const std::string prefix = (work_dir / "drr_").string();
  auto args = plastimatch_drr_arguments(view_ct, volume_mha, prefix);
  if (!args.ok()) return args.status();
  std::string log;
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<std::string> env;
  if (threads > 0) env.push_back("OMP_NUM_THREADS=" + std::to_string(threads));
  if (Status s = run_process(*args, &log, env); !s.ok()) return s.with_context(log.substr(0, 400));
  PeerDrr out;
  out.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  auto image = read_plastimatch_pfm(prefix + "0000.pfm");
  if (!image.ok()) return image.status();
  out.line_integrals = std::move(image).value();
  if (const auto at = log.find("Total time:"); at != std::string::npos) {
    out.reported_render_s = std::atof(log.c_str() + at + std::strlen("Total time:"));
  }
  return out;
}

}  // namespace lftrack::studies
