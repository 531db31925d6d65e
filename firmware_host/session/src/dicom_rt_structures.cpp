// The RT Structure Set reader (dicom_rt.hpp): its ROIs and their contours, read strictly.

#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcuid.h>
#include <dcmtk/dcmrt/drtstrct.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <sstream>

#include "dicom_rt_common.hpp"
#include "lftrack/session/dicom_rt.hpp"

namespace lftrack::session {
namespace rt {
namespace {

// ContourData's text, taken from the dataset's own item rather than from dcmrt: dcmrt's string
// getter assembles a multi-valued DS value by value, each found from the start (DCMTK 3.6.7:
// 7 s for 60,000 points), and its number getter reads "3abc" as 3 and "0x10" as 0.
std::string contour_data_text(DcmDataset& ds, std::size_t roi_contour, std::size_t contour) {
  DcmItem* roi_item = nullptr;
  DcmItem* contour_item = nullptr;
  const char* text = nullptr;
  Uint32 length = 0;
  if (ds.findAndGetSequenceItem(DCM_ROIContourSequence, roi_item, static_cast<signed long>(roi_contour))
          .bad() ||
      roi_item->findAndGetSequenceItem(DCM_ContourSequence, contour_item, static_cast<signed long>(contour))
          .bad() ||
      contour_item->findAndGetString(DCM_ContourData, text, length).bad() || text == nullptr)
    return {};
  return std::string(text, length);
}

}  // namespace
}  // namespace rt

Result<RtStructureSet> read_rt_structure_set(const std::filesystem::path& file) {
  const std::string where = file.string();
  DcmFileFormat format;
  LFTRACK_RETURN_IF_ERROR(rt::load(file, &format));
  DcmDataset& ds = *format.getDataset();
  LFTRACK_RETURN_IF_ERROR(
      rt::check_kind(ds, file, UID_RTStructureSetStorage, "RTSTRUCT", "an RT Structure Set"));
  DRTStructureSetIOD set;
  if (const OFCondition c = set.read(ds); c.bad())
    return corrupt_data(where + ": DCMTK cannot read it as an RT Structure Set: " + c.text());

  RtStructureSet out;
  out.file = where;
  out.label = rt::text_from([&](OFString& v) { return set.getStructureSetLabel(v); });
  out.patient_id = rt::text_from([&](OFString& v) { return set.getPatientID(v); });
  DRTReferencedFrameOfReferenceSequence& frames = set.getReferencedFrameOfReferenceSequence();
  for (std::size_t i = 0; i < frames.getNumberOfItems(); ++i) {
    DRTReferencedFrameOfReferenceSequence::Item& frame = frames.getItem(i);
    const std::string uid = rt::text_from([&](OFString& v) { return frame.getFrameOfReferenceUID(v); });
    if (!uid.empty()) out.frame_of_reference_uids.push_back(uid);
    DRTRTReferencedStudySequence& studies = frame.getRTReferencedStudySequence();
    for (std::size_t s = 0; s < studies.getNumberOfItems(); ++s) {
      DRTRTReferencedSeriesSequence& series = studies.getItem(s).getRTReferencedSeriesSequence();
      for (std::size_t k = 0; k < series.getNumberOfItems(); ++k) {
        const std::string series_uid =
            rt::text_from([&](OFString& v) { return series.getItem(k).getSeriesInstanceUID(v); });
        if (!series_uid.empty()) out.referenced_series_uids.push_back(series_uid);
      }
    }
  }

  std::map<int, std::size_t> by_number;
  DRTStructureSetROISequence& rois = set.getStructureSetROISequence();
  for (std::size_t i = 0; i < rois.getNumberOfItems(); ++i) {
    DRTStructureSetROISequence::Item& roi = rois.getItem(i);
    RtStructure s;
    s.name = rt::text_from([&](OFString& v) { return roi.getROIName(v); });
    Sint32 number = 0;
    if (roi.getROINumber(number).bad())
      return corrupt_data(where + ": structure " + std::to_string(i + 1) + " '" + s.name +
                          "' has no ROI Number");
    s.roi_number = number;
    s.frame_of_reference_uid =
        rt::text_from([&](OFString& v) { return roi.getReferencedFrameOfReferenceUID(v); });
    if (!by_number.emplace(number, out.structures.size()).second)
      return corrupt_data(where + ": two structures have ROI Number " + std::to_string(number));
    out.structures.push_back(std::move(s));
  }

  std::size_t total_points = 0;
  DRTROIContourSequence& roi_contours = set.getROIContourSequence();
  for (std::size_t i = 0; i < roi_contours.getNumberOfItems(); ++i) {
    DRTROIContourSequence::Item& roi_contour = roi_contours.getItem(i);
    Sint32 number = 0;
    if (roi_contour.getReferencedROINumber(number).bad()) continue;
    const auto found = by_number.find(number);
    if (found == by_number.end()) continue;
    RtStructure& s = out.structures[found->second];
    DRTContourSequence& contours = roi_contour.getContourSequence();
    for (std::size_t k = 0; k < contours.getNumberOfItems(); ++k) {
      DRTContourSequence::Item& contour = contours.getItem(k);
      const std::string about = where + ": structure '" + s.name + "' (ROI " + std::to_string(number) +
                                "), contour " + std::to_string(k + 1) + ": ";
      const std::string data = rt::contour_data_text(ds, i, k);
      const std::size_t values = data.find_first_not_of(' ') == std::string::npos
                                     ? 0
                                     : std::count(data.begin(), data.end(), '\\') + 1;
      if (values % 3 != 0)
        return corrupt_data(about + "ContourData (3006,0050) holds " + std::to_string(values) +
                            " numbers, not a multiple of 3");
      const std::size_t points = values / 3;
      Sint32 stated = 0;
      if (contour.getNumberOfContourPoints(stated).good() && (stated < 0 || std::size_t(stated) != points))
        return corrupt_data(about + "NumberOfContourPoints (3006,0046) is " + std::to_string(stated) +
                            " but ContourData holds " + std::to_string(points) + " points");
      if (points > kMaxPointsPerContour)
        return out_of_range(about + std::to_string(points) + " points; lftrack reads at most " +
                            std::to_string(kMaxPointsPerContour) + " in one contour");
      total_points += points;
      if (total_points > kMaxPointsPerStructureSet)
        return out_of_range(where + ": more than " + std::to_string(kMaxPointsPerStructureSet) +
                            " contour points in all; lftrack reads no more");
      std::vector<double> xyz;
      if (!rt::parse_decimals(data, &xyz) || xyz.size() != values)
        return corrupt_data(about +
                            "ContourData (3006,0050) holds a value that is not a finite decimal number");
      RtContour c;
      c.geometric_type = rt::text_from([&](OFString& v) { return contour.getContourGeometricType(v); });
      c.points_ct_mm.reserve(points);
      for (std::size_t p = 0; p < points; ++p)
        c.points_ct_mm.emplace_back(xyz[3 * p], xyz[3 * p + 1], xyz[3 * p + 2]);
      s.contours.push_back(std::move(c));
    }
  }
  return out;
}

}  // namespace lftrack::session
