#include "dicom_rt_common.hpp"

#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/oflog/oflog.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <mutex>
#include <sstream>

namespace lftrack::session::rt {

namespace fs = std::filesystem;

void quiet_dcmtk() {
  static std::once_flag once;
  std::call_once(once, [] {
    OFLog::getLogger("dcmtk.dcmrt").setLogLevel(OFLogger::OFF_LOG_LEVEL);
    OFLog::getLogger("dcmtk.dcmdata").setLogLevel(OFLogger::FATAL_LOG_LEVEL);
  });
}

std::string trimmed(const OFString& value) {
  const std::string s = value.c_str();
  const auto first = s.find_first_not_of(' ');
  if (first == std::string::npos) return {};
  return s.substr(first, s.find_last_not_of(' ') - first + 1);
}

std::string text_of(DcmItem& item, const DcmTagKey& tag) {
  OFString value;
  if (item.findAndGetOFStringArray(tag, value).bad()) return {};
  return trimmed(value);
}

std::string point_text(const Eigen::Vector3d& p) {
  std::ostringstream s;
  s.precision(10);
  s << '(' << p.x() << ", " << p.y() << ", " << p.z() << ')';
  return s.str();
}

bool parse_decimals(const std::string& text, std::vector<double>* out) {
  out->clear();
  if (text.find_first_not_of(' ') == std::string::npos) return true;
  const char* p = text.data();
  const char* const end = p + text.size();
  while (true) {
    const char* stop = std::find(p, end, '\\');
    while (p < stop && *p == ' ') ++p;
    const char* last = stop;
    while (last > p && last[-1] == ' ') --last;
    if (p < last && *p == '+') ++p;
    double v = 0;
    const auto [ptr, ec] = std::from_chars(p, last, v);
    if (p == last || ec != std::errc() || ptr != last || !std::isfinite(v)) return false;
    out->push_back(v);
    if (stop == end) return true;
    p = stop + 1;
  }
}

Status load(const fs::path& file, DcmFileFormat* format, const DcmTagKey& stop_at) {
  quiet_dcmtk();
  std::error_code ec;
  if (!fs::exists(file, ec)) return not_found(file.string() + ": no such file");
  if (!fs::is_regular_file(file, ec)) return invalid_argument(file.string() + ": not a regular file");
  if (fs::file_size(file, ec) == 0) return corrupt_data(file.string() + ": an empty file, not DICOM");
  const OFCondition c = format->loadFileUntilTag(file.c_str(), EXS_Unknown, EGL_noChange, DCM_MaxReadLength,
                                                 ERM_autoDetect, stop_at);
  if (c.bad())
    return corrupt_data(file.string() + ": not a DICOM file, or a damaged one (DCMTK: " + c.text() + ")");
  // Names and labels as UTF-8 whatever Specific Character Set (0008,0005) the file declares, so
  // that a name typed on the command line matches and the scene holds valid text.
  if (const OFCondition u = format->convertToUTF8(); u.bad())
    return unsupported(
        file.string() +
        ": its text cannot be read as UTF-8 from its Specific Character Set (0008,0005) (DCMTK: " +
        std::string(u.text()) + ")");
  return {};
}

Status check_kind(DcmDataset& ds, const fs::path& file, const char* sop_class, const char* modality,
                  const std::string& what) {
  const std::string sop = text_of(ds, DCM_SOPClassUID), mod = text_of(ds, DCM_Modality);
  if (sop == sop_class) return {};
  if (sop.empty() && mod == modality && ds.putAndInsertString(DCM_SOPClassUID, sop_class).good()) return {};
  return invalid_argument(file.string() + ": not " + what + " (SOP Class UID '" + sop + "', Modality '" +
                          mod + "')");
}

}  // namespace lftrack::session::rt
