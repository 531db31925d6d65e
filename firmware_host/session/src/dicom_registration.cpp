#include "lftrack/session/dicom_registration.hpp"
#include "lftrack/session/scene_fingerprint.hpp"

#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcuid.h>
#include <openssl/sha.h>

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <set>
#include <sstream>
#include <vector>

namespace lftrack::session {
namespace {

namespace fs = std::filesystem;

std::string text_of(DcmItem& item, const DcmTagKey& tag) {
  OFString value;
  if (item.findAndGetOFStringArray(tag, value).good()) return value.c_str();
  return {};
}

// A DS value: at most 16 characters, as many significant digits as fit.
std::string decimal_string(double v) {
  for (int digits = 15; digits > 1; --digits) {
    char text[64];
    std::snprintf(text, sizeof text, "%.*g", digits, v);
    if (std::string(text).size() <= 16) return text;
  }
  return "0";
}

std::string new_uid() {
  char uid[100];
  dcmGenerateUniqueIdentifier(uid, SITE_INSTANCE_UID_ROOT);
  return uid;
}

Status put(DcmItem* item, const DcmTagKey& tag, const std::string& value) {
  const OFCondition c = item->putAndInsertString(tag, value.c_str());
  if (c.bad()) return internal_error(std::string("DICOM: cannot set ") + DcmTag(tag).getTagName() + ": " + c.text());
  return {};
}

Result<DcmItem*> new_item(DcmItem* parent, const DcmTagKey& sequence) {
  DcmItem* item = nullptr;
  const OFCondition c = parent->findOrCreateSequenceItem(sequence, item, -2);
  if (c.bad() || item == nullptr) return internal_error("DICOM: cannot add an item to a sequence: " + std::string(c.text()));
  return item;
}

// One Registration Sequence item: a Frame of Reference (and the images registered in it, if any)
// and the rigid matrix from it to the room.
Status add_registration(DcmItem* dataset, const std::string& frame_of_reference,
                        const std::vector<std::pair<std::string, std::string>>& images, const Eigen::Matrix4d& matrix,
                        const std::string& comment) {
  auto item = new_item(dataset, DCM_RegistrationSequence);
  if (!item.ok()) return item.status();
  LFTRACK_RETURN_IF_ERROR(put(*item, DCM_FrameOfReferenceUID, frame_of_reference));
  for (const auto& [sop_class, sop_instance] : images) {
    auto image = new_item(*item, DCM_ReferencedImageSequence);
    if (!image.ok()) return image.status();
    LFTRACK_RETURN_IF_ERROR(put(*image, DCM_ReferencedSOPClassUID, sop_class));
    LFTRACK_RETURN_IF_ERROR(put(*image, DCM_ReferencedSOPInstanceUID, sop_instance));
  }
  auto registration = new_item(*item, DCM_MatrixRegistrationSequence);
  if (!registration.ok()) return registration.status();
  LFTRACK_RETURN_IF_ERROR(put(*registration, DCM_FrameOfReferenceTransformationComment, comment));
  auto type = new_item(*registration, DCM_RegistrationTypeCodeSequence);
  if (!type.ok()) return type.status();
  LFTRACK_RETURN_IF_ERROR(put(*type, DCM_CodeValue, "125024"));  // CID 7100
  LFTRACK_RETURN_IF_ERROR(put(*type, DCM_CodingSchemeDesignator, "DCM"));
  LFTRACK_RETURN_IF_ERROR(put(*type, DCM_CodeMeaning, "Image Content-based Alignment"));
  auto m = new_item(*registration, DCM_MatrixSequence);
  if (!m.ok()) return m.status();
  std::string values;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) {
      if (!values.empty()) values += '\\';
      values += decimal_string(matrix(r, c));
    }
  LFTRACK_RETURN_IF_ERROR(put(*m, DCM_FrameOfReferenceTransformationMatrix, values));
  return put(*m, DCM_FrameOfReferenceTransformationMatrixType, "RIGID");
}

}  // namespace

Result<CtDicomIdentity> read_ct_dicom_identity(const fs::path& folder) {
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) return not_found(folder.string() + ": not a folder of DICOM files");
  CtDicomIdentity id;
  std::set<std::string> series, frames;
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(folder, ec))
    if (entry.is_regular_file(ec)) files.push_back(entry.path());
  std::sort(files.begin(), files.end());
  for (const fs::path& file : files) {
    DcmFileFormat format;
    // Headers only: elements longer than 4 KiB (the pixel data) stay on disk.
    if (format.loadFile(file.c_str(), EXS_Unknown, EGL_noChange, 4096, ERM_autoDetect).bad()) continue;
    DcmDataset& ds = *format.getDataset();
    const std::string sop_class = text_of(ds, DCM_SOPClassUID), sop_instance = text_of(ds, DCM_SOPInstanceUID);
    if (sop_class.empty() || sop_instance.empty())
      return failed_precondition(file.string() + ": a DICOM file without SOP Class or Instance UID; a registration "
                                                 "cannot reference it");
    if (id.instances.empty()) {
      id.patient_name = text_of(ds, DCM_PatientName);
      id.patient_id = text_of(ds, DCM_PatientID);
      id.patient_birth_date = text_of(ds, DCM_PatientBirthDate);
      id.patient_sex = text_of(ds, DCM_PatientSex);
      id.study_uid = text_of(ds, DCM_StudyInstanceUID);
      id.study_id = text_of(ds, DCM_StudyID);
      id.study_date = text_of(ds, DCM_StudyDate);
      id.study_time = text_of(ds, DCM_StudyTime);
      id.accession_number = text_of(ds, DCM_AccessionNumber);
      id.referring_physician = text_of(ds, DCM_ReferringPhysicianName);
    }
    series.insert(text_of(ds, DCM_SeriesInstanceUID));
    frames.insert(text_of(ds, DCM_FrameOfReferenceUID));
    id.instances.emplace_back(sop_class, sop_instance);
  }
  if (id.instances.empty()) return not_found(folder.string() + ": no DICOM files");
  if (series.size() != 1 || frames.size() != 1)
    return failed_precondition(folder.string() + ": the files belong to " + std::to_string(series.size()) +
                               " series and " + std::to_string(frames.size()) +
                               " Frames of Reference; a planning CT is one series");
  id.series_uid = *series.begin();
  id.frame_of_reference_uid = *frames.begin();
  if (id.frame_of_reference_uid.empty())
    return failed_precondition(folder.string() + ": the series has no Frame of Reference UID to register");
  if (id.study_uid.empty() || id.series_uid.empty())
    return failed_precondition(folder.string() + ": the series has no Study or Series Instance UID");
  return id;
}

Result<CtDicomIdentity> scene_ct_dicom_identity(const Scene& scene) {
  if (scene.ct.is_builtin_phantom())
    return failed_precondition("the scene's CT is the built-in phantom: it has no DICOM Frame of Reference to "
                               "register (a DICOM registration needs a DICOM planning CT)");
  std::error_code ec;
  if (!fs::is_directory(scene.ct.path, ec))
    return failed_precondition("the scene's CT " + scene.ct.path +
                               " is not a DICOM series (NIfTI carries no Frame of Reference UID); a DICOM "
                               "registration needs the planning CT as DICOM");
  return read_ct_dicom_identity(scene.ct.path);
}

std::string room_frame_of_reference_uid(const Scene& scene) {
  const std::string text = "lftrack room frame\n" + room_geometry_text(scene);
  unsigned char hash[SHA256_DIGEST_LENGTH];
  SHA256(reinterpret_cast<const unsigned char*>(text.data()), text.size(), hash);
  // The first 128 bits of the hash as a decimal number: long division of the big-endian bytes by 10.
  std::vector<unsigned> bytes(hash, hash + 16);
  std::string digits;
  while (std::any_of(bytes.begin(), bytes.end(), [](unsigned b) { return b != 0; })) {
    unsigned remainder = 0;
    for (unsigned& b : bytes) {
      const unsigned value = remainder * 256 + b;
      b = value / 10;
      remainder = value % 10;
    }
    digits.push_back(static_cast<char>('0' + remainder));
  }
  if (digits.empty()) digits.push_back('0');
  std::reverse(digits.begin(), digits.end());
  return "2.25." + digits;
}

Status write_spatial_registration(const fs::path& file, const CtDicomIdentity& ct, const SpatialRegistration& r) {
  const Eigen::Matrix4d T = r.T_room_from_ct.matrix();
  if (!T.allFinite()) return invalid_argument("DICOM registration: the pose is not finite");
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  if ((R.transpose() * R - Eigen::Matrix3d::Identity()).norm() > 1e-6 || std::abs(R.determinant() - 1) > 1e-6)
    return invalid_argument("DICOM registration: the pose is not a rigid transform");
  if (r.room_frame_of_reference_uid.empty() || ct.frame_of_reference_uid.empty())
    return invalid_argument("DICOM registration: both Frames of Reference are needed");
  LFTRACK_RETURN_IF_ERROR(check_registration_path(file));

  DcmFileFormat format;
  DcmDataset* ds = format.getDataset();
  char date[16], clock[16];
  const std::time_t now = std::time(nullptr);
  std::tm local{};
  localtime_r(&now, &local);
  std::strftime(date, sizeof date, "%Y%m%d", &local);
  std::strftime(clock, sizeof clock, "%H%M%S", &local);
  const std::string instance_uid = new_uid();
  for (const auto& [tag, value] : std::vector<std::pair<DcmTagKey, std::string>>{
           {DCM_SpecificCharacterSet, "ISO_IR 100"},
           {DCM_SOPClassUID, UID_SpatialRegistrationStorage},
           {DCM_SOPInstanceUID, instance_uid},
           {DCM_PatientName, ct.patient_name},
           {DCM_PatientID, ct.patient_id},
           {DCM_PatientBirthDate, ct.patient_birth_date},
           {DCM_PatientSex, ct.patient_sex},
           {DCM_StudyInstanceUID, ct.study_uid},
           {DCM_StudyID, ct.study_id},
           {DCM_StudyDate, ct.study_date},
           {DCM_StudyTime, ct.study_time},
           {DCM_AccessionNumber, ct.accession_number},
           {DCM_ReferringPhysicianName, ct.referring_physician},
           {DCM_Modality, "REG"},
           {DCM_SeriesInstanceUID, new_uid()},
           {DCM_SeriesNumber, "900"},
           {DCM_SeriesDescription, "lftrack registration"},
           {DCM_Laterality, ""},  // type 2C: a spine is no paired structure
           {DCM_FrameOfReferenceUID, r.room_frame_of_reference_uid},
           {DCM_PositionReferenceIndicator, ""},
           {DCM_Manufacturer, "lftrack"},
           {DCM_ManufacturerModelName, "lftrack"},
           {DCM_InstanceNumber, "1"},
           {DCM_ContentDate, date},
           {DCM_ContentTime, clock},
           {DCM_ContentLabel, "LFTRACK_REG"},
           {DCM_ContentDescription, r.description.substr(0, 64)},
           {DCM_ContentCreatorName, ""}})
    LFTRACK_RETURN_IF_ERROR(put(ds, tag, value));
  LFTRACK_RETURN_IF_ERROR(add_registration(ds, r.room_frame_of_reference_uid, {}, Eigen::Matrix4d::Identity(),
                                           "the treatment room (registered frame)"));
  LFTRACK_RETURN_IF_ERROR(
      add_registration(ds, ct.frame_of_reference_uid, ct.instances, T, "planning CT to room: T_room_from_ct"));
  auto series = new_item(ds, DCM_ReferencedSeriesSequence);
  if (!series.ok()) return series.status();
  LFTRACK_RETURN_IF_ERROR(put(*series, DCM_SeriesInstanceUID, ct.series_uid));
  for (const auto& [sop_class, sop_instance] : ct.instances) {
    auto instance = new_item(*series, DCM_ReferencedInstanceSequence);
    if (!instance.ok()) return instance.status();
    LFTRACK_RETURN_IF_ERROR(put(*instance, DCM_ReferencedSOPClassUID, sop_class));
    LFTRACK_RETURN_IF_ERROR(put(*instance, DCM_ReferencedSOPInstanceUID, sop_instance));
  }
  // Written into a file this call creates (mkstemp: O_EXCL, a fresh name) beside the target, then
  // linked into place: no half-written object under its name, and nothing else written through.
  std::string partial = file.string() + ".partial-XXXXXX";
  const int fd = ::mkstemp(partial.data());
  if (fd < 0) return io_error(file.string() + ": cannot create a file beside it: " + std::strerror(errno));
  ::close(fd);
  const OFCondition saved = format.saveFile(partial.c_str(), EXS_LittleEndianExplicit);
  Status placed;
  if (saved.bad()) {
    placed = io_error(file.string() + ": cannot write: " + saved.text());
  } else if (::link(partial.c_str(), file.c_str()) != 0) {
    placed = errno == EEXIST ? failed_precondition(file.string() + " appeared while writing; not replacing it")
                             : io_error(file.string() + ": cannot place the registration: " + std::strerror(errno));
  }
  ::unlink(partial.c_str());
  return placed;
}

Status check_registration_path(const fs::path& file) {
  if (file.empty() || !file.has_filename())
    return invalid_argument(file.string() + ": names no file for the registration");
  std::error_code ec;
  if (fs::exists(fs::symlink_status(file, ec)))
    return failed_precondition(file.string() + " exists; a registration is never written over another file");
  const fs::path parent = file.has_parent_path() ? file.parent_path() : fs::path(".");
  if (!fs::is_directory(parent, ec)) return not_found("the folder " + parent.string() + " does not exist");
  return {};
}

}  // namespace lftrack::session
