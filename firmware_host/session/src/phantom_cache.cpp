#include "lftrack/host/phantom_cache.hpp"

#include <elf.h>
#include <link.h>
#include <spdlog/spdlog.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <random>
#include <sstream>
#include <system_error>

namespace lftrack::host {
namespace {

namespace fs = std::filesystem;

// The file: a text header padded with NULs to kHeaderBytes, then the voxels as the host's float32
// in the CT's storage order. The header's first lines must equal expected_header() exactly; the
// last line gives the voxels' CRC-32.
constexpr std::size_t kHeaderBytes = 4096;
constexpr const char* kMagic = "lftrack spine phantom cache 1";

std::uint32_t payload_crc(const std::vector<float>& values) {
  uLong crc = crc32(0L, Z_NULL, 0);
  const auto* bytes = reinterpret_cast<const Bytef*>(values.data());
  std::size_t left = values.size() * sizeof(float);
  while (left > 0) {  // zlib takes 32-bit lengths
    const auto chunk = static_cast<uInt>(std::min<std::size_t>(left, 1u << 30));
    crc = crc32(crc, bytes, chunk);
    bytes += chunk;
    left -= chunk;
  }
  return static_cast<std::uint32_t>(crc);
}

// The options, every double to the last bit (%.17g), as the header and the file name hold them.
std::string options_text(const sim::SpinePhantomOptions& o) {
  char text[512];
  std::snprintf(text, sizeof text, "seed=%llu size=%dx%dx%d spacing_mm=%.17g,%.17g,%.17g centre_mm=%.17g,%.17g,%.17g noise_hu=%.17g",
                static_cast<unsigned long long>(o.seed), o.size.x(), o.size.y(), o.size.z(), o.spacing_mm.x(),
                o.spacing_mm.y(), o.spacing_mm.z(), o.centre_mm.x(), o.centre_mm.y(), o.centre_mm.z(), o.noise_hu);
  return text;
}

std::string expected_header(const sim::SpinePhantomOptions& o, const std::string& build_id, std::size_t voxels) {
  return std::string(kMagic) + "\nbuild " + build_id + "\noptions " + options_text(o) + "\nvoxels " +
         std::to_string(voxels) + "\n";
}

fs::path cache_file(const sim::SpinePhantomOptions& o, const fs::path& dir, const std::string& build_id) {
  const std::string text = options_text(o);
  const auto crc = crc32(0L, reinterpret_cast<const Bytef*>(text.data()), static_cast<uInt>(text.size()));
  char name[128];
  std::snprintf(name, sizeof name, "spine-phantom-%08lx-%s.ct", static_cast<unsigned long>(crc), build_id.c_str());
  return dir / name;
}

// The voxels of `file` into `phantom` (whose geometry is set), or why not.
Status read_cached(const fs::path& file, const std::string& header, sim::SpinePhantom* phantom) {
  std::error_code ec;
  const fs::file_status status = fs::status(file, ec);
  if (!fs::exists(status)) return not_found("no cached copy");
  // Opened only as a plain file: a FIFO would block the open until someone wrote to it.
  if (!fs::is_regular_file(status)) return corrupt_data("it is not a plain file");
  std::ifstream in(file, std::ios::binary);
  if (!in) return io_error("it cannot be read");
  std::string head(kHeaderBytes, '\0');
  if (!in.read(head.data(), static_cast<std::streamsize>(head.size())))
    return corrupt_data("its header is cut short");
  if (head.compare(0, header.size(), header) != 0) return corrupt_data("its header names another phantom or build");
  unsigned long crc = 0;
  if (std::sscanf(head.c_str() + header.size(), "crc32 %lx", &crc) != 1) return corrupt_data("its header has no CRC");
  std::vector<float>& values = phantom->ct.values;
  values.resize(static_cast<std::size_t>(phantom->ct.geometry.voxel_count()));
  const auto bytes = static_cast<std::streamsize>(values.size() * sizeof(float));
  if (!in.read(reinterpret_cast<char*>(values.data()), bytes)) return corrupt_data("its voxels are cut short");
  if (in.peek() != std::char_traits<char>::eof()) return corrupt_data("it is longer than its voxels");
  if (payload_crc(values) != crc) return corrupt_data("its voxels fail their CRC-32");
  return {};
}

// Writes `phantom` to `file` through a temporary file in the same folder, renamed into place.
Status write_cached(const fs::path& file, const std::string& header, const sim::SpinePhantom& phantom) {
  std::error_code ec;
  fs::create_directories(file.parent_path(), ec);
  if (ec) return io_error("cannot make " + file.parent_path().string() + ": " + ec.message());
  std::string head = header + "crc32 ";
  char crc[16];
  std::snprintf(crc, sizeof crc, "%08x\n", static_cast<unsigned>(payload_crc(phantom.ct.values)));
  head += crc;
  head.resize(kHeaderBytes, '\0');
  std::random_device entropy;
  const fs::path temporary =
      file.string() + ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(entropy());
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    out.write(head.data(), static_cast<std::streamsize>(head.size()));
    out.write(reinterpret_cast<const char*>(phantom.ct.values.data()),
              static_cast<std::streamsize>(phantom.ct.values.size() * sizeof(float)));
    out.close();
    if (!out) {
      fs::remove(temporary, ec);
      return io_error("cannot write " + temporary.string());
    }
  }
  fs::rename(temporary, file, ec);
  if (ec) {
    fs::remove(temporary, ec);
    return io_error("cannot rename into " + file.string() + ": " + ec.message());
  }
  return {};
}

// dl_iterate_phdr visits the main program first (its name is empty); its PT_NOTE segments hold the
// NT_GNU_BUILD_ID note when the linker wrote one (--build-id, Debian's default).
int find_build_id(dl_phdr_info* info, std::size_t, void* data) {
  auto* id = static_cast<std::optional<std::string>*>(data);
  for (int s = 0; s < info->dlpi_phnum; ++s) {
    const ElfW(Phdr)& segment = info->dlpi_phdr[s];
    if (segment.p_type != PT_NOTE) continue;
    const auto* at = reinterpret_cast<const unsigned char*>(info->dlpi_addr + segment.p_vaddr);
    const unsigned char* end = at + segment.p_memsz;
    while (at + sizeof(ElfW(Nhdr)) <= end) {
      ElfW(Nhdr) note;
      std::memcpy(&note, at, sizeof note);
      const unsigned char* name = at + sizeof note;
      const unsigned char* desc = name + ((note.n_namesz + 3u) & ~3u);
      if (desc + note.n_descsz > end) break;
      if (note.n_type == NT_GNU_BUILD_ID && note.n_namesz == 4 && std::memcmp(name, "GNU", 4) == 0) {
        std::string hex;
        char digits[3];
        for (unsigned i = 0; i < note.n_descsz; ++i) {
          std::snprintf(digits, sizeof digits, "%02x", desc[i]);
          hex += digits;
        }
        *id = hex;
        return 1;
      }
      at = desc + ((note.n_descsz + 3u) & ~3u);
    }
  }
  return 1;  // only the main program
}

}  // namespace

std::optional<std::string> program_build_id() {
  static const std::optional<std::string> id = [] {
    std::optional<std::string> found;
    dl_iterate_phdr(find_build_id, &found);
    return found;
  }();
  return id;
}

fs::path cache_dir_from_environment() {
  const char* dir = std::getenv(kCacheDirVariable);
  return dir != nullptr ? fs::path(dir) : fs::path();
}

Result<sim::SpinePhantom> cached_spine_phantom(const sim::SpinePhantomOptions& options, const fs::path& dir,
                                               tracking::ThreadPool* pool, PhantomCacheUse* use) {
  PhantomCacheUse ignored;
  if (use == nullptr) use = &ignored;
  *use = PhantomCacheUse::kOff;
  const std::optional<std::string> build_id = program_build_id();
  if (dir.empty() || !build_id) return sim::make_spine_phantom(options, pool);

  auto layout = sim::spine_phantom_layout(options);
  if (!layout.ok()) return layout.status();
  sim::SpinePhantom phantom = std::move(layout).value();
  const fs::path file = cache_file(options, dir, *build_id);
  const std::string header =
      expected_header(options, *build_id, static_cast<std::size_t>(phantom.ct.geometry.voxel_count()));
  const Status read = read_cached(file, header, &phantom);
  if (read.ok()) {
    *use = PhantomCacheUse::kLoaded;
    return phantom;
  }
  if (read.code() != StatusCode::kNotFound)
    spdlog::info("cached phantom {} not used ({}); making it anew", file.string(), read.message());

  auto made = sim::make_spine_phantom(options, pool);
  if (!made.ok()) return made.status();
  const Status written = write_cached(file, header, *made);
  *use = written.ok() ? PhantomCacheUse::kGenerated : PhantomCacheUse::kUnwritten;
  if (!written.ok()) spdlog::warn("phantom cache: {} (the phantom is made anew each run)", written.message());
  return made;
}

}  // namespace lftrack::host
