#pragma once
// What the RT Plan and RT Structure Set readers share (dicom_rt.cpp, dicom_rt_structures.cpp):
// a DICOM file loaded as UTF-8 with DCMTK's logs quiet, its kind checked, and text and DS values
// read strictly. Private to the session library.

#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcitem.h>

#include <Eigen/Core>
#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/tracking/status.hpp"

namespace lftrack::session::rt {  // named: these files compile in unity batches beside other DICOM code

// dcmrt logs every attribute of the whole IOD that it finds missing or malformed, most of which
// these readers never use, and dcmdata logs parse errors: the Status returned carries what
// matters, with the file's name. Called by load().
void quiet_dcmtk();
std::string trimmed(const OFString& value);                // without its padding spaces
std::string text_of(DcmItem& item, const DcmTagKey& tag);  // the tag's value, trimmed ("" if none)
// One value of a dcmrt getter (`get` is called with an OFString and the position), trimmed.
template <class Get>
std::string text_from(Get get) {
  OFString value;
  if (get(value).bad()) return {};
  return trimmed(value);
}
std::string point_text(const Eigen::Vector3d& p);  // "(x, y, z)" to 10 digits
// A DS value (decimal numbers separated by backslashes): each number whole (no trailing text, no hex) and
// finite. Returns false otherwise.
bool parse_decimals(const std::string& text, std::vector<double>* out);
// `file` loaded (up to `stop_at`), its text as UTF-8; a missing, empty or damaged file refused.
Status load(const std::filesystem::path& file, DcmFileFormat* format,
            const DcmTagKey& stop_at = DCM_UndefinedTagKey);
// Whether `ds` is of `sop_class`; a dataset without a SOP Class UID but of `modality` is taken as
// one, and given the SOP Class UID (dcmrt's read() refuses a dataset without it).
Status check_kind(DcmDataset& ds, const std::filesystem::path& file, const char* sop_class,
                  const char* modality, const std::string& what);

}  // namespace lftrack::session::rt
