#include "rt_writer.hpp"

#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcuid.h>

#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace lftrack::test {
namespace {

namespace fs = std::filesystem;

void check(const OFCondition& c, const std::string& what) {
  if (c.bad()) throw std::runtime_error("DCMTK: " + what + ": " + c.text());
}

void put(DcmItem* item, const DcmTagKey& tag, const std::string& value) {
  check(item->putAndInsertString(tag, value.c_str()), std::string("set ") + DcmTag(tag).getTagName());
}

DcmItem* add_item(DcmItem* parent, const DcmTagKey& sequence) {
  DcmItem* item = nullptr;
  check(parent->findOrCreateSequenceItem(sequence, item, -2),
        std::string("add to ") + DcmTag(sequence).getTagName());
  return item;
}

// A DS value: at most 16 characters, as many significant digits as fit.
std::string decimal(double v) {
  for (int digits = 15; digits > 1; --digits) {
    char text[64];
    std::snprintf(text, sizeof text, "%.*g", digits, v);
    if (std::string(text).size() <= 16) return text;
  }
  return "0";
}

std::string decimals(const Eigen::Vector3d& p) {
  return decimal(p.x()) + "\\" + decimal(p.y()) + "\\" + decimal(p.z());
}

std::string new_uid() {
  char uid[100];
  return dcmGenerateUniqueIdentifier(uid, SITE_INSTANCE_UID_ROOT);
}

// Patient, General Study, (RT) Series, General Equipment and SOP Common modules.
void put_common(DcmDataset* ds, const char* sop_class, const char* modality, const std::string& study_uid) {
  put(ds, DCM_SOPClassUID, sop_class);
  put(ds, DCM_SOPInstanceUID, new_uid());
  put(ds, DCM_PatientName, "Test^Phantom");
  put(ds, DCM_PatientID, "LFTRACK-TEST");
  put(ds, DCM_PatientBirthDate, "");
  put(ds, DCM_PatientSex, "O");
  put(ds, DCM_StudyInstanceUID, study_uid);
  put(ds, DCM_StudyDate, "20240102");
  put(ds, DCM_StudyTime, "120000");
  put(ds, DCM_ReferringPhysicianName, "");
  put(ds, DCM_StudyID, "1");
  put(ds, DCM_AccessionNumber, "");
  put(ds, DCM_Modality, modality);
  put(ds, DCM_SeriesInstanceUID, new_uid());
  put(ds, DCM_SeriesNumber, "1");
  put(ds, DCM_OperatorsName, "");
  put(ds, DCM_Manufacturer, "lftrack tests");
}

// Implicit VR Little Endian: the default transfer syntax, with no 64 KiB limit on a value (a
// long contour's data).
void save(DcmFileFormat& format, const fs::path& file) {
  check(format.saveFile(file.c_str(), EXS_LittleEndianImplicit), "save " + file.string());
}

void put_control_point(DcmItem* cp, int index, double cumulative_weight) {
  put(cp, DCM_ControlPointIndex, std::to_string(index));
  put(cp, DCM_CumulativeMetersetWeight, decimal(cumulative_weight));
}

void put_first_control_point(DcmItem* cp) {
  put_control_point(cp, 0, 0);
  put(cp, DCM_NominalBeamEnergy, "6");
  for (const char* jaw : {"X", "Y"}) {
    DcmItem* position = add_item(cp, DCM_BeamLimitingDevicePositionSequence);
    put(position, DCM_RTBeamLimitingDeviceType, jaw);
    put(position, DCM_LeafJawPositions, "-50\\50");
  }
  put(cp, DCM_GantryAngle, "0");
  put(cp, DCM_GantryRotationDirection, "NONE");
  put(cp, DCM_BeamLimitingDeviceAngle, "0");
  put(cp, DCM_BeamLimitingDeviceRotationDirection, "NONE");
  put(cp, DCM_PatientSupportAngle, "0");
  put(cp, DCM_PatientSupportRotationDirection, "NONE");
  put(cp, DCM_TableTopEccentricAngle, "0");
  put(cp, DCM_TableTopEccentricRotationDirection, "NONE");
  put(cp, DCM_TableTopVerticalPosition, "");
  put(cp, DCM_TableTopLongitudinalPosition, "");
  put(cp, DCM_TableTopLateralPosition, "");
  check(cp->putAndInsertFloat32(DCM_TableTopPitchAngle, 0), "set TableTopPitchAngle");
  put(cp, DCM_TableTopPitchRotationDirection, "NONE");
  check(cp->putAndInsertFloat32(DCM_TableTopRollAngle, 0), "set TableTopRollAngle");
  put(cp, DCM_TableTopRollRotationDirection, "NONE");
}

void put_beam(DcmItem* beam, const RtPlanSpec::Beam& b, bool tolerance_table) {
  put(beam, DCM_BeamNumber, std::to_string(b.number));
  put(beam, DCM_BeamName, b.name);
  put(beam, DCM_BeamType, "STATIC");
  put(beam, DCM_RadiationType, "PHOTON");
  put(beam, DCM_TreatmentMachineName, "LINAC");
  put(beam, DCM_PrimaryDosimeterUnit, "MU");
  put(beam, DCM_SourceAxisDistance, "1000");
  for (const char* jaw : {"X", "Y"}) {
    DcmItem* device = add_item(beam, DCM_BeamLimitingDeviceSequence);
    put(device, DCM_RTBeamLimitingDeviceType, jaw);
    put(device, DCM_NumberOfLeafJawPairs, "1");
  }
  put(beam, DCM_TreatmentDeliveryType, "TREATMENT");
  for (const DcmTagKey& count :
       {DCM_NumberOfWedges, DCM_NumberOfCompensators, DCM_NumberOfBoli, DCM_NumberOfBlocks})
    put(beam, count, "0");
  put(beam, DCM_FinalCumulativeMetersetWeight, "1");
  put(beam, DCM_NumberOfControlPoints, "2");
  DcmItem* first = add_item(beam, DCM_ControlPointSequence);
  put_first_control_point(first);
  DcmItem* last = add_item(beam, DCM_ControlPointSequence);
  put_control_point(last, 1, 1);
  put(b.isocentre_in_first_control_point ? first : last, DCM_IsocenterPosition, decimals(b.isocentre_mm));
  put(beam, DCM_ReferencedPatientSetupNumber, "1");
  if (tolerance_table) put(beam, DCM_ReferencedToleranceTableNumber, "1");
}

}  // namespace

void write_rt_plan(const fs::path& file, const RtPlanSpec& spec) {
  DcmFileFormat format;
  DcmDataset* ds = format.getDataset();
  put_common(ds, UID_RTPlanStorage, "RTPLAN", new_uid());
  if (!spec.frame_of_reference_uid.empty()) {
    put(ds, DCM_FrameOfReferenceUID, spec.frame_of_reference_uid);
    put(ds, DCM_PositionReferenceIndicator, "");
  }
  put(ds, DCM_RTPlanLabel, spec.label);
  put(ds, DCM_RTPlanDate, "20240102");
  put(ds, DCM_RTPlanTime, "120000");
  put(ds, DCM_RTPlanGeometry, "PATIENT");
  DcmItem* structures = add_item(ds, DCM_ReferencedStructureSetSequence);
  put(structures, DCM_ReferencedSOPClassUID, UID_RTStructureSetStorage);
  put(structures, DCM_ReferencedSOPInstanceUID, new_uid());
  if (spec.tolerances) {
    const auto& t = *spec.tolerances;
    DcmItem* table = add_item(ds, DCM_ToleranceTableSequence);
    put(table, DCM_ToleranceTableNumber, "1");
    put(table, DCM_TableTopLateralPositionTolerance, decimal(t[0]));
    put(table, DCM_TableTopLongitudinalPositionTolerance, decimal(t[1]));
    put(table, DCM_TableTopVerticalPositionTolerance, decimal(t[2]));
    check(table->putAndInsertFloat32(DCM_TableTopPitchAngleTolerance, Float32(t[3])), "set pitch tolerance");
    check(table->putAndInsertFloat32(DCM_TableTopRollAngleTolerance, Float32(t[4])), "set roll tolerance");
    put(table, DCM_PatientSupportAngleTolerance, decimal(t[5]));
  }
  DcmItem* setup = add_item(ds, DCM_PatientSetupSequence);
  put(setup, DCM_PatientSetupNumber, "1");
  if (!spec.patient_position.empty()) put(setup, DCM_PatientPosition, spec.patient_position);
  DcmItem* fraction = add_item(ds, DCM_FractionGroupSequence);
  put(fraction, DCM_FractionGroupNumber, "1");
  put(fraction, DCM_NumberOfFractionsPlanned, "1");
  put(fraction, DCM_NumberOfBeams, std::to_string(spec.beams.size()));
  put(fraction, DCM_NumberOfBrachyApplicationSetups, "0");
  for (const RtPlanSpec::Beam& b : spec.beams) {
    DcmItem* referenced = add_item(fraction, DCM_ReferencedBeamSequence);
    put(referenced, DCM_BeamMeterset, "100");
    put(referenced, DCM_ReferencedBeamNumber, std::to_string(b.number));
    put_beam(add_item(ds, DCM_BeamSequence), b, spec.tolerances.has_value());
  }
  put(ds, DCM_ApprovalStatus, "UNAPPROVED");
  save(format, file);
}

void write_rt_structure_set(const fs::path& file, const RtStructSpec& spec) {
  DcmFileFormat format;
  DcmDataset* ds = format.getDataset();
  put_common(ds, UID_RTStructureSetStorage, "RTSTRUCT", spec.study_uid);
  put(ds, DCM_FrameOfReferenceUID, spec.frame_of_reference_uid);
  put(ds, DCM_PositionReferenceIndicator, "");
  put(ds, DCM_StructureSetLabel, spec.label);
  put(ds, DCM_StructureSetDate, "20240102");
  put(ds, DCM_StructureSetTime, "120000");
  DcmItem* frame = add_item(ds, DCM_ReferencedFrameOfReferenceSequence);
  put(frame, DCM_FrameOfReferenceUID, spec.frame_of_reference_uid);
  DcmItem* study = add_item(frame, DCM_RTReferencedStudySequence);
  // Detached Study Management (retired), which PS3.3 still names here.
  put(study, DCM_ReferencedSOPClassUID, "1.2.840.10008.3.1.2.3.1");
  put(study, DCM_ReferencedSOPInstanceUID, spec.study_uid);
  DcmItem* series = add_item(study, DCM_RTReferencedSeriesSequence);
  put(series, DCM_SeriesInstanceUID, spec.series_uid);
  // One placeholder slice: the sequence is type 1, and these tests have no CT slices to name.
  DcmItem* image = add_item(series, DCM_ContourImageSequence);
  put(image, DCM_ReferencedSOPClassUID, UID_CTImageStorage);
  put(image, DCM_ReferencedSOPInstanceUID, new_uid());

  for (const RtStructSpec::Structure& s : spec.structures) {
    DcmItem* roi = add_item(ds, DCM_StructureSetROISequence);
    put(roi, DCM_ROINumber, std::to_string(s.number));
    put(roi, DCM_ReferencedFrameOfReferenceUID, spec.frame_of_reference_uid);
    put(roi, DCM_ROIName, s.name);
    put(roi, DCM_ROIGenerationAlgorithm, "MANUAL");

    DcmItem* roi_contour = add_item(ds, DCM_ROIContourSequence);
    put(roi_contour, DCM_ROIDisplayColor, "255\\0\\0");
    for (std::size_t k = 0; k < s.contours.size(); ++k) {
      DcmItem* contour = add_item(roi_contour, DCM_ContourSequence);
      put(contour, DCM_ContourNumber, std::to_string(k + 1));
      put(contour, DCM_ContourGeometricType, s.geometric_type);
      put(contour, DCM_NumberOfContourPoints, std::to_string(s.contours[k].size()));
      std::string data;
      for (const Eigen::Vector3d& p : s.contours[k]) {
        if (!data.empty()) data += '\\';
        data += decimals(p);
      }
      put(contour, DCM_ContourData, data);
    }
    put(roi_contour, DCM_ReferencedROINumber, std::to_string(s.number));

    DcmItem* observation = add_item(ds, DCM_RTROIObservationsSequence);
    put(observation, DCM_ObservationNumber, std::to_string(s.number));
    put(observation, DCM_ReferencedROINumber, std::to_string(s.number));
    put(observation, DCM_RTROIInterpretedType, "");
    put(observation, DCM_ROIInterpreter, "");
  }
  save(format, file);
}

void edit_dicom_value(const fs::path& file, std::uint16_t group, std::uint16_t element,
                      const std::optional<std::string>& value) {
  DcmFileFormat format;
  check(format.loadFile(file.c_str()), "load " + file.string());
  check(format.loadAllDataIntoMemory(), "load " + file.string());  // it is written over
  DcmDataset* ds = format.getDataset();
  const DcmTagKey tag(group, element);
  DcmElement* found = nullptr;
  if (!value) {
    ds->findAndDeleteElement(tag, OFFalse, OFTrue);
  } else if (ds->findAndGetElement(tag, found, OFTrue).good() && found) {
    check(found->putString(value->c_str()), "edit " + file.string());
  } else {
    put(ds, tag, *value);
  }
  check(format.saveFile(file.c_str(), EXS_Unknown), "save " + file.string());
}

std::vector<std::vector<Eigen::Vector3d>> lumbar_ct_vertebral_body() {
  std::vector<std::vector<Eigen::Vector3d>> contours;
  for (int k = 28; k <= 38; ++k) {
    std::vector<Eigen::Vector3d> ring;
    for (int i = 0; i < 48; ++i) {
      const double a = 2 * M_PI * i / 48;
      ring.emplace_back(6 + 18 * std::cos(a), 107 + 14 * std::sin(a), 85.91 + 3 * k);
    }
    contours.push_back(ring);
  }
  return contours;
}

}  // namespace lftrack::test
