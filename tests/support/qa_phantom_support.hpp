#pragma once
// What the package and QA tests share: a shell command's exit code and output, and the QA phantom's
// light fields (scenes/qa-phantom.yaml, the room the package installs as configuration) built
// once into the test cache and shared by every test that runs that room.

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "cli_text.hpp"
#include "test_data.hpp"

namespace lftrack::test {

// `command` run by /bin/sh in `dir`, stdout and stderr together into dir/LOG.
inline CliRun shell(const std::string& command, const std::filesystem::path& dir,
                    const std::string& log = "out.txt") {
  const std::filesystem::path file = dir / log;
  const std::string line =
      "cd " + quoted(dir.string()) + " && { " + command + " ; } >" + quoted(file.string()) + " 2>&1";
  CliRun r;
  const int status = std::system(line.c_str());
  if (status != -1 && WIFEXITED(status)) r.exit_code = WEXITSTATUS(status);
  r.out = contents(file);
  return r;
}

inline std::filesystem::path qa_phantom_scene() {
  return std::filesystem::path(LFTRACK_SOURCE_DIR) / "scenes" / "qa-phantom.yaml";
}

// The loop command the QA phantom's service runs (LFTRACK_LOOP in `env_file`, by default the
// package's debian/qa-phantom.env: `sim --room`), its words joined by spaces; empty if the file
// or the line is missing. Reads the plain `KEY=word word` form that file uses (one pair of
// enclosing double quotes and trailing blanks dropped), not every form systemd accepts.
inline std::string qa_phantom_loop(
    const std::filesystem::path& env_file = std::filesystem::path(LFTRACK_SOURCE_DIR) / "debian" /
                                            "qa-phantom.env") {
  const std::string text = contents(env_file);
  const std::string key = "\nLFTRACK_LOOP=";
  const std::size_t at = ("\n" + text).find(key);
  if (at == std::string::npos) return {};
  const std::size_t start = at + key.size() - 1;  // in `text`
  std::string value = text.substr(start, text.find('\n', start) - start);
  while (!value.empty() && (value.back() == ' ' || value.back() == '\t' || value.back() == '\r'))
    value.pop_back();
  if (value.size() >= 2 && value.front() == '"' && value.back() == '"')
    value = value.substr(1, value.size() - 2);
  return value;
}

// The QA phantom's light fields (tracking and the simulator's), built by `program` where missing
// or stale; a field is saved by rename, so two tests building at once never see half a file.
inline std::filesystem::path qa_phantom_fields(const std::string& program, const std::filesystem::path& scene,
                                               const std::filesystem::path& log_dir) {
  const std::filesystem::path fields = test_cache_dir() / "qa-phantom-fields";
  std::filesystem::create_directories(fields);
  // One builder at a time (several test programs want these fields at once); the others wait and
  // find them up to date.
  const CliRun r = shell("flock " + quoted((test_cache_dir() / "qa-phantom-fields.lock").string()) + " " +
                             quoted(program) + " -q precompute --scene " + quoted(scene.string()) + " -o " +
                             quoted(fields.string()),
                         log_dir, "precompute.txt");
  if (r.exit_code != 0) return {};
  // Readable by the unprivileged user the service tests run as.
  std::error_code ignored;
  for (auto p = fields; p != p.root_path() && p != test_cache_dir().parent_path(); p = p.parent_path())
    std::filesystem::permissions(p, std::filesystem::perms::others_read | std::filesystem::perms::others_exec,
                                 std::filesystem::perm_options::add, ignored);
  std::error_code walk;
  for (std::filesystem::recursive_directory_iterator it(fields, walk), end; !walk && it != end;
       it.increment(walk))
    std::filesystem::permissions(
        it->path(),
        std::filesystem::perms::others_read |
            (it->is_directory(ignored) ? std::filesystem::perms::others_exec : std::filesystem::perms::none),
        std::filesystem::perm_options::add, ignored);
  return fields;
}

}  // namespace lftrack::test
