#pragma once
// The built-in phantom's CT, generated once per program build and kept in a cache folder.
//
// The phantom (phantom::make_spine_phantom) is 26 million voxels of analytic anatomy and noise: about
// 3 s of CPU, the largest part of every short `lftrack sim` and of every closed-loop test. It is
// a pure function of its options and of the code that draws it, so a copy made by the same build
// of the same program can stand for it. A cached copy is used only when
//   - the folder is given (cached_spine_phantom's `dir`, or LFTRACK_CACHE_DIR for the program),
//   - its file names the same options and the same code: the ELF build ID of the running
//     executable (which changes with any change of the code linked into it), of lftrack's own
//     libraries where they are shared, of libm and libc (glibc picks cos and log by CPU at run
//     time), and whether the CPU has FMA,
//   - its header repeats both, and its voxels pass their CRC-32.
// Anything else (no build ID, a damaged, truncated or foreign file, a FIFO, device, folder or
// link to one in its place, a folder that cannot be read or written, or has less than twice a
// copy plus 1 GB free) falls back to generating the phantom, which is always correct; the cache
// never fails a run and never blocks on what it opens. The log says where a copy was read or
// kept (info), and why one was not used or could not be written (warning). A new copy is written
// to a temporary file of its own and renamed into place, so processes sharing the folder see a whole file or
// none. Each time a copy is read or written, the same program's copies from other builds of the same phantom
// are deleted (one copy per program and phantom, about 100 MB), and temporary files an hour old (a writer
// killed mid-copy). Delete the folder at any time.

#include <filesystem>
#include <optional>
#include <string>

#include "lftrack/phantom/spine_phantom.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::session {

// The environment variable naming the program's cache folder (unset or empty: no cache). The
// test suite sets it for every test (tests/CMakeLists.txt), so its processes share one phantom.
inline constexpr const char* kCacheDirVariable = "LFTRACK_CACHE_DIR";

// The running executable's GNU build ID in hex, or nothing when the linker wrote none.
std::optional<std::string> program_build_id();

// What happened to the cache in one call, for the log and the tests.
enum class PhantomCacheUse {
  kOff,        // no folder, or no build ID: generated
  kLoaded,     // read from the folder
  kGenerated,  // not in the folder (or not usable): generated and written there
  kUnwritten,  // generated, and the folder would not take the copy (logged once per call)
};

// The phantom for `options`: from `dir` when it holds this build's copy, else generated (with
// `pool`) and written there. An empty `dir` turns the cache off. Fails only as
// phantom::make_spine_phantom fails (invalid options). `use`, if given, says which path was taken.
Result<phantom::SpinePhantom> cached_spine_phantom(const phantom::SpinePhantomOptions& options,
                                                   const std::filesystem::path& dir,
                                                   tracking::ThreadPool* pool,
                                                   PhantomCacheUse* use = nullptr);

// The folder LFTRACK_CACHE_DIR names, or an empty path.
std::filesystem::path cache_dir_from_environment();

}  // namespace lftrack::session
