#include "lftrack/session/phantom_cache.hpp"

#include <elf.h>
#include <fcntl.h>
#include <gnu/libc-version.h>
#include <link.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <system_error>

#include "lftrack/tracking/checksum.hpp"
#include "lftrack/tracking/cpu_features.hpp"

namespace lftrack::session {

using phantom::make_spine_phantom;
using phantom::spine_phantom_layout;
using phantom::SpinePhantom;
using phantom::SpinePhantomOptions;
namespace {

namespace fs = std::filesystem;

// The file: a text header padded with NULs to kHeaderBytes, then the voxels as the host's float32
// in the CT's storage order. The header's first lines (magic, code key, options, voxel count) must
// equal those cached_spine_phantom expects exactly; the last line gives the voxels' CRC-32.
constexpr std::size_t kHeaderBytes = 4096;
constexpr const char* kMagic = "lftrack spine phantom cache 1";

std::uint32_t payload_crc(const std::vector<float>& values) {
  return tracking::crc32_of(values.data(), values.size() * sizeof(float));
}

// The options, every double to the last bit (%.17g), as the header and the file name hold them.
// Every field of SpinePhantomOptions must be here, or two phantoms would share a file: a field
// added to the struct changes its size and stops the build until it is added below.
static_assert(sizeof(SpinePhantomOptions) == 80, "a new phantom option: add it to options_text");
std::string options_text(const SpinePhantomOptions& o) {
  char text[512];
  std::snprintf(text, sizeof text, "seed=%llu size=%dx%dx%d spacing_mm=%.17g,%.17g,%.17g centre_mm=%.17g,%.17g,%.17g noise_hu=%.17g",
                static_cast<unsigned long long>(o.seed), o.size.x(), o.size.y(), o.size.z(), o.spacing_mm.x(),
                o.spacing_mm.y(), o.spacing_mm.z(), o.centre_mm.x(), o.centre_mm.y(), o.centre_mm.z(), o.noise_hu);
  return text;
}

std::string crc_hex(const std::string& text) {
  char hex[16];
  std::snprintf(hex, sizeof hex, "%08x", static_cast<unsigned>(tracking::crc32_of(text.data(), text.size())));
  return hex;
}

// Files of one phantom made by one program (wherever it was built) share this prefix; the code
// key follows it. Other builds' copies under the same prefix are pruned.
std::string file_prefix(const SpinePhantomOptions& o) {
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  return "spine-phantom-" + crc_hex(options_text(o)) + "-" + crc_hex(ec ? std::string("?") : exe.string()) + "-";
}

// The cache's housekeeping once `kept` was read or written: other builds' copies of the same
// phantom by the same program, and temporary files an hour old (a process killed while writing).
void prune(const fs::path& dir, const std::string& prefix, const fs::path& kept) {
  std::error_code ec;
  const auto now = fs::file_time_type::clock::now();
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.rfind("spine-phantom-", 0) != 0) continue;
    std::error_code e;
    const bool stale_copy = name.rfind(prefix, 0) == 0 && name.size() > 3 &&
                            name.compare(name.size() - 3, 3, ".ct") == 0 && it->path() != kept;
    const bool old_temporary = name.find(".tmp-") != std::string::npos &&
                               now - fs::last_write_time(it->path(), e) > std::chrono::hours(1) && !e;
    if (stale_copy || old_temporary) fs::remove(it->path(), e);
  }
}

// Reads exactly `size` bytes from `fd`; false on an error or the end of the file before them.
bool read_all(int fd, char* bytes, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::read(fd, bytes, size);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    bytes += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

// The file descriptor of `file`, closed when it goes.
struct OpenFile {
  int fd = -1;
  ~OpenFile() {
    if (fd >= 0) ::close(fd);
  }
};

// The voxels of `file` into `phantom` (whose geometry is set), or why not.
Status read_voxels(const fs::path& file, const std::string& header, SpinePhantom* phantom) {
  std::error_code ec;
  if (!fs::exists(fs::symlink_status(file, ec))) return not_found("no cached copy");
  // Opened without blocking (a FIFO would block the open until someone wrote to it), then judged
  // by what was opened, not by the name: a plain file of exactly the header and the voxels.
  // Anything else (a FIFO, a device, a folder, a link that loops or leads nowhere, /proc's
  // files of size 0, a sparse file grown past the voxels) is never read.
  OpenFile in;
  in.fd = ::open(file.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (in.fd < 0) return corrupt_data(std::string("it cannot be opened (") + std::strerror(errno) + ")");
  struct stat st {};
  if (::fstat(in.fd, &st) != 0 || !S_ISREG(st.st_mode)) return corrupt_data("it is not a plain file");
  std::vector<float>& values = phantom->ct.values;
  const std::size_t voxels = static_cast<std::size_t>(phantom->ct.geometry.voxel_count());
  const std::size_t expected = kHeaderBytes + voxels * sizeof(float);
  if (static_cast<std::uint64_t>(st.st_size) < kHeaderBytes) return corrupt_data("its header is cut short");
  if (static_cast<std::uint64_t>(st.st_size) < expected) return corrupt_data("its voxels are cut short");
  if (static_cast<std::uint64_t>(st.st_size) > expected) return corrupt_data("it is longer than its voxels");
  ::fcntl(in.fd, F_SETFL, ::fcntl(in.fd, F_GETFL) & ~O_NONBLOCK);
  std::string head(kHeaderBytes, '\0');
  if (!read_all(in.fd, head.data(), head.size())) return corrupt_data("its header is cut short");
  if (head.compare(0, header.size(), header) != 0) return corrupt_data("its header names another phantom or build");
  unsigned long crc = 0;
  if (std::sscanf(head.c_str() + header.size(), "crc32 %lx", &crc) != 1) return corrupt_data("its header has no CRC");
  values.resize(voxels);
  if (!read_all(in.fd, reinterpret_cast<char*>(values.data()), voxels * sizeof(float)))
    return corrupt_data("its voxels are cut short");
  if (payload_crc(values) != crc) return corrupt_data("its voxels fail their CRC-32");
  return {};
}

Status read_cached(const fs::path& file, const std::string& header, SpinePhantom* phantom) {
  Status read = read_voxels(file, header, phantom);
  if (!read.ok()) std::vector<float>().swap(phantom->ct.values);  // not held while the phantom is made
  return read;
}

// Writes `phantom` to `file` through a temporary file in the same folder (mkstemp: a name of its
// own, created exclusively), renamed into place.
Status write_cached(const fs::path& file, const std::string& header, const SpinePhantom& phantom) {
  std::error_code ec;
  fs::create_directories(file.parent_path(), ec);
  if (ec) return io_error("cannot make " + file.parent_path().string() + ": " + ec.message());
  std::string head = header + "crc32 ";
  char crc[16];
  std::snprintf(crc, sizeof crc, "%08x\n", static_cast<unsigned>(payload_crc(phantom.ct.values)));
  head += crc;
  head.resize(kHeaderBytes, '\0');
  // Not written into the last of a disk: the copy is a convenience, the disk may be the journals'.
  const std::uintmax_t copy_bytes = head.size() + phantom.ct.values.size() * sizeof(float);
  const fs::space_info space = fs::space(file.parent_path(), ec);
  if (!ec && space.available < 2 * copy_bytes + (std::uintmax_t{1} << 30))
    return io_error("only " + std::to_string(space.available >> 20) + " MB free in " + file.parent_path().string() +
                    " (a copy is " + std::to_string(copy_bytes >> 20) + " MB; it is written only with 1 GB to spare)");
  std::string temporary = file.string() + ".tmp-XXXXXX";
  const int fd = ::mkstemp(temporary.data());
  if (fd < 0) return io_error("cannot create a file in " + file.parent_path().string() + ": " + std::strerror(errno));
  ::fchmod(fd, 0644);
  bool written = true;
  const auto write_all = [&](const char* bytes, std::size_t size) {
    while (written && size > 0) {
      const ssize_t n = ::write(fd, bytes, size);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        written = false;
        break;
      }
      bytes += n;
      size -= static_cast<std::size_t>(n);
    }
  };
  write_all(head.data(), head.size());
  write_all(reinterpret_cast<const char*>(phantom.ct.values.data()), phantom.ct.values.size() * sizeof(float));
  int write_errno = written ? 0 : errno;
  if (::close(fd) != 0 && written) {
    written = false;
    write_errno = errno;
  }
  if (!written) {
    fs::remove(temporary, ec);
    return io_error("cannot write " + temporary + ": " + std::strerror(write_errno));
  }
  std::error_code renamed;
  fs::rename(temporary, file, renamed);
  if (renamed) {
    fs::remove(temporary, ec);
    return io_error("cannot rename into " + file.string() + ": " + renamed.message());
  }
  return {};
}

// The GNU build ID of one loaded object in hex (its PT_NOTE segments hold NT_GNU_BUILD_ID when
// the linker wrote one: --build-id, Debian's default), or empty. Notes are padded to the
// segment's alignment (4 or 8). An ID under 8 bytes is taken as none.
std::string build_id_of(const dl_phdr_info* info) {
  for (int s = 0; s < info->dlpi_phnum; ++s) {
    const ElfW(Phdr)& segment = info->dlpi_phdr[s];
    if (segment.p_type != PT_NOTE) continue;
    const std::size_t align = segment.p_align == 8 ? 8 : 4;
    const auto pad = [align](std::size_t n) { return (n + align - 1) & ~(align - 1); };
    const auto* at = reinterpret_cast<const unsigned char*>(info->dlpi_addr + segment.p_vaddr);
    std::size_t left = segment.p_memsz;
    while (left >= sizeof(ElfW(Nhdr))) {
      ElfW(Nhdr) note;
      std::memcpy(&note, at, sizeof note);
      const std::size_t name_bytes = pad(note.n_namesz), desc_bytes = pad(note.n_descsz);
      if (name_bytes > left - sizeof note || desc_bytes > left - sizeof note - name_bytes) break;
      const unsigned char* name = at + sizeof note;
      const unsigned char* desc = name + name_bytes;
      if (note.n_type == NT_GNU_BUILD_ID && note.n_namesz == 4 && std::memcmp(name, "GNU", 4) == 0) {
        if (note.n_descsz < 8) return {};
        std::string hex;
        char digits[3];
        for (unsigned i = 0; i < note.n_descsz; ++i) {
          std::snprintf(digits, sizeof digits, "%02x", desc[i]);
          hex += digits;
        }
        return hex;
      }
      at = desc + desc_bytes;
      left -= sizeof note + name_bytes + desc_bytes;
    }
  }
  return {};
}

// The code a phantom's voxels depend on: the program (first object dl_iterate_phdr visits, its
// name empty), lftrack's own libraries when built shared, and libm and libc (glibc picks cos and
// log by CPU at run time, and an upgrade may change them), plus whether this CPU has FMA.
struct CodeIdentity {
  std::string program;  // the program's build ID; empty: none, and no cache
  std::string others;   // the rest, as text
};

int collect_identity(dl_phdr_info* info, std::size_t, void* data) {
  auto* identity = static_cast<CodeIdentity*>(data);
  const std::string name = info->dlpi_name != nullptr ? info->dlpi_name : "";
  if (name.empty() && identity->program.empty() && identity->others.empty()) {
    identity->program = build_id_of(info);
    identity->others = "?";  // the program has been seen
    return 0;
  }
  const std::string file = fs::path(name).filename().string();
  if (file.rfind("libm.so", 0) == 0 || file.rfind("libc.so", 0) == 0 || file.rfind("liblftrack", 0) == 0)
    identity->others += file + "=" + build_id_of(info) + ";";
  return 0;
}

const CodeIdentity& code_identity() {
  static const CodeIdentity identity = [] {
    CodeIdentity found;
    dl_iterate_phdr(collect_identity, &found);
    found.others +=
        std::string("glibc ") + gnu_get_libc_version() + (tracking::cpu_features().fma ? " fma" : "");
    return found;
  }();
  return identity;
}

// The key in the file's name and header: the program's build ID and a digest of the rest.
std::string code_key() { return code_identity().program + "-" + crc_hex(code_identity().others); }

}  // namespace

std::optional<std::string> program_build_id() {
  const std::string& id = code_identity().program;
  return id.empty() ? std::nullopt : std::optional<std::string>(id);
}

fs::path cache_dir_from_environment() {
  const char* dir = std::getenv(kCacheDirVariable);
  return dir != nullptr ? fs::path(dir) : fs::path();
}

Result<SpinePhantom> cached_spine_phantom(const SpinePhantomOptions& options, const fs::path& dir,
                                          tracking::ThreadPool* pool, PhantomCacheUse* use) {
  PhantomCacheUse ignored;
  if (use == nullptr) use = &ignored;
  *use = PhantomCacheUse::kOff;
  if (dir.empty()) return make_spine_phantom(options, pool);
  if (!program_build_id()) {
    static std::once_flag said;
    std::call_once(said, [&] {
      spdlog::info("phantom cache {}: this program has no build ID, so no copy can be told apart; not used",
                   dir.string());
    });
    return make_spine_phantom(options, pool);
  }

  auto layout = spine_phantom_layout(options);
  if (!layout.ok()) return layout.status();
  SpinePhantom phantom = std::move(layout).value();
  const std::string prefix = file_prefix(options);
  const std::string key = code_key();
  const fs::path file = dir / (prefix + key + ".ct");
  const std::string header =
      std::string(kMagic) + "\nbuild " + key + "\noptions " + options_text(options) + "\nvoxels " +
      std::to_string(phantom.ct.geometry.voxel_count()) + "\n";
  std::error_code ec;
  const fs::path shown = fs::absolute(file, ec);
  const Status read = read_cached(file, header, &phantom);
  if (read.ok()) {
    *use = PhantomCacheUse::kLoaded;
    spdlog::info("built-in phantom read from {}", shown.string());
    prune(dir, prefix, file);  // temporaries left by a writer that was killed
    return phantom;
  }
  if (read.code() != StatusCode::kNotFound)
    spdlog::warn("cached phantom {} not used ({}); making it anew", shown.string(), read.message());

  auto made = make_spine_phantom(options, pool);
  if (!made.ok()) return made.status();
  const Status written = write_cached(file, header, *made);
  *use = written.ok() ? PhantomCacheUse::kGenerated : PhantomCacheUse::kUnwritten;
  if (written.ok()) {
    spdlog::info("built-in phantom kept in {} for later runs of this build", shown.string());
    prune(dir, prefix, file);
  } else {
    spdlog::warn("phantom cache: {} (the phantom is made anew each run)", written.message());
  }
  return made;
}

}  // namespace lftrack::session
