#include "lftrack/session/dicom_rt.hpp"

#include "dicom_rt_common.hpp"

#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcuid.h>
#include <dcmtk/dcmrt/drtplan.h>
#include <dcmtk/oflog/oflog.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <map>
#include <mutex>
#include <set>
#include <sstream>

namespace lftrack::session {
namespace rt {  // named: these files compile in unity batches beside other DICOM code
namespace {

namespace fs = std::filesystem;

// ---- RT Plan ----

const std::set<std::string>& known_patient_positions() {
  static const std::set<std::string> known{"HFS", "FFS", "HFP", "FFP", "HFDL", "HFDR", "FFDL", "FFDR"};
  return known;
}

std::string beam_text(const RtPlanBeam& b) {
  return "beam " + std::to_string(b.number) + " '" + b.name + "'";
}

std::string beam_list(const std::vector<RtPlanBeam>& beams) {
  std::string list;
  for (const RtPlanBeam& b : beams) {
    if (!list.empty()) list += ", ";
    list += std::to_string(b.number) + " '" + b.name + "'";
  }
  return list;
}

Result<RtPlanBeam> read_beam(DRTBeamSequence::Item& item, std::size_t index, const std::string& where) {
  RtPlanBeam beam;
  beam.name = text_from([&](OFString& v) { return item.getBeamName(v); });
  Sint32 number = 0;
  if (item.getBeamNumber(number).bad())
    return corrupt_data(where + ": beam " + std::to_string(index + 1) +
                        " of the Beam Sequence has no Beam Number");
  beam.number = number;
  DRTControlPointSequence& points = item.getControlPointSequence();
  if (points.getNumberOfItems() == 0)
    return corrupt_data(where + ": " + beam_text(beam) + " has no control point");
  const std::string iso =
      text_from([&](OFString& v) { return points.getItem(0).getIsocenterPosition(v, -1); });
  std::vector<double> xyz;
  if (iso.empty())
    return corrupt_data(where + ": " + beam_text(beam) +
                        " has no Isocenter Position (300A,012C) in its first control point");
  if (!parse_decimals(iso, &xyz) || xyz.size() != 3)
    return corrupt_data(where + ": " + beam_text(beam) +
                        "'s Isocenter Position (300A,012C) is not 3 finite numbers: '" + iso + "'");
  beam.isocentre_ct_mm = {xyz[0], xyz[1], xyz[2]};
  return beam;
}

// The patient position of the setup the beam references ("" if none); refused when the reference
// leads nowhere or the position is unknown.
Result<std::string> patient_position(DRTPlanIOD& plan, DRTBeamSequence::Item& item, const RtPlanBeam& beam,
                                     const std::string& where) {
  DRTPatientSetupSequence& setups = plan.getPatientSetupSequence();
  Sint32 wanted = 0;
  const bool references = item.getReferencedPatientSetupNumber(wanted).good();
  DRTPatientSetupSequence::Item* setup = nullptr;
  if (!references && setups.getNumberOfItems() == 1) setup = &setups.getItem(0);
  for (std::size_t i = 0; references && !setup && i < setups.getNumberOfItems(); ++i) {
    Sint32 number = 0;
    if (setups.getItem(i).getPatientSetupNumber(number).good() && number == wanted)
      setup = &setups.getItem(i);
  }
  if (references && !setup)
    return corrupt_data(where + ": " + beam_text(beam) + " references patient setup " +
                        std::to_string(wanted) + ", which the plan does not have");
  if (!setup) return std::string();
  const std::string position = text_from([&](OFString& v) { return setup->getPatientPosition(v); });
  if (!position.empty() && known_patient_positions().count(position) == 0)
    return unsupported(where + ": " + beam_text(beam) + "'s patient setup gives the patient position '" +
                       position +
                       "', which lftrack does not know (HFS, FFS, HFP, FFP, HFDL, HFDR, FFDL, FFDR)");
  return position;
}

Result<TableTopTolerances> tolerances(DRTPlanIOD& plan, DRTBeamSequence::Item& item, const RtPlanBeam& beam,
                                      const std::string& where) {
  TableTopTolerances t;
  Sint32 wanted = 0;
  if (item.getReferencedToleranceTableNumber(wanted).bad()) return t;
  DRTToleranceTableSequence& tables = plan.getToleranceTableSequence();
  for (std::size_t i = 0; i < tables.getNumberOfItems(); ++i) {
    DRTToleranceTableSequence::Item& table = tables.getItem(i);
    Sint32 number = 0;
    if (table.getToleranceTableNumber(number).bad() || number != wanted) continue;
    t.table_number = number;
    // A tolerance the table gives (DS or FL, by its VR), which must be finite.
    using Table = DRTToleranceTableSequence::Item;
    bool finite = true;
    auto take = [&](auto get, auto value, std::optional<double>* out) {
      if ((table.*get)(value, 0).bad()) return;
      *out = static_cast<double>(value);
      finite = finite && std::isfinite(**out);
    };
    // A DS tolerance from its text, parsed strictly (dcmrt's number getter reads "3abc" as 3).
    bool well_formed = true;
    auto decimal = [&](OFCondition (Table::*get)(OFString&, signed long) const, std::optional<double>* out) {
      OFString text;
      if ((table.*get)(text, 0).bad() || text.empty()) return;
      std::vector<double> value;
      if (!parse_decimals(trimmed(text), &value) || value.size() != 1) {
        well_formed = false;
        return;
      }
      *out = value[0];
    };
    auto single = [&](OFCondition (Table::*get)(Float32&, unsigned long) const, std::optional<double>* out) {
      take(get, Float32(0), out);
    };
    decimal(&Table::getTableTopLateralPositionTolerance, &t.lateral_mm);
    decimal(&Table::getTableTopLongitudinalPositionTolerance, &t.longitudinal_mm);
    decimal(&Table::getTableTopVerticalPositionTolerance, &t.vertical_mm);
    single(&Table::getTableTopPitchAngleTolerance, &t.pitch_deg);
    single(&Table::getTableTopRollAngleTolerance, &t.roll_deg);
    decimal(&Table::getPatientSupportAngleTolerance, &t.patient_support_deg);
    if (!finite || !well_formed)
      return corrupt_data(where + ": tolerance table " + std::to_string(number) +
                          " holds a tolerance that is not one finite decimal number");
    return t;
  }
  return corrupt_data(where + ": " + beam_text(beam) + " references tolerance table " +
                      std::to_string(wanted) + ", which the plan does not have");
}

}  // namespace
}  // namespace rt

Result<RtPlanSetup> read_rt_plan(const std::filesystem::path& file, const std::string& beam) {
  const std::string where = file.string();
  DcmFileFormat format;
  LFTRACK_RETURN_IF_ERROR(rt::load(file, &format));
  DcmDataset& ds = *format.getDataset();
  if (rt::text_of(ds, DCM_SOPClassUID) == UID_RTIonPlanStorage || ds.tagExists(DCM_IonBeamSequence))
    return unsupported(where +
                       ": an RT Ion Plan; ion plans are not supported (photon and electron RT Plans are)");
  LFTRACK_RETURN_IF_ERROR(rt::check_kind(ds, file, UID_RTPlanStorage, "RTPLAN", "an RT Plan"));
  DRTPlanIOD plan;
  if (const OFCondition c = plan.read(ds); c.bad())
    return corrupt_data(where + ": DCMTK cannot read it as an RT Plan: " + c.text());

  RtPlanSetup setup;
  setup.file = where;
  setup.label = rt::text_from([&](OFString& v) { return plan.getRTPlanLabel(v); });
  setup.patient_id = rt::text_from([&](OFString& v) { return plan.getPatientID(v); });
  setup.frame_of_reference_uid = rt::text_from([&](OFString& v) { return plan.getFrameOfReferenceUID(v); });
  if (setup.frame_of_reference_uid.empty())
    return failed_precondition(where +
                               ": the plan has no Frame of Reference UID (0020,0052); its isocentre "
                               "cannot be placed in the CT");
  DRTBeamSequence& items = plan.getBeamSequence();
  if (items.getNumberOfItems() == 0) return failed_precondition(where + ": the plan has no beam");
  for (std::size_t i = 0; i < items.getNumberOfItems(); ++i) {
    auto b = rt::read_beam(items.getItem(i), i, where);
    if (!b.ok()) return b.status();
    for (const RtPlanBeam& other : setup.beams)
      if (other.number == b->number)
        return corrupt_data(where + ": two beams are numbered " + std::to_string(b->number) +
                            " (Beam Number (300A,00C0) names one beam): " + rt::beam_text(other) + " and " +
                            rt::beam_text(*b));
    setup.beams.push_back(*b);
  }

  // The chosen beams: the one named, or every beam (which must then agree).
  std::vector<std::size_t> chosen;
  if (beam.empty()) {
    for (std::size_t i = 0; i < setup.beams.size(); ++i) chosen.push_back(i);
    const Eigen::Vector3d& first = setup.beams.front().isocentre_ct_mm;
    std::vector<Eigen::Vector3d> distinct{first};
    for (const RtPlanBeam& b : setup.beams)
      if (std::none_of(distinct.begin(), distinct.end(),
                       [&](const Eigen::Vector3d& p) { return (p - b.isocentre_ct_mm).norm() <= 0.01; }))
        distinct.push_back(b.isocentre_ct_mm);
    if (distinct.size() > 1) {
      std::string list;
      for (const RtPlanBeam& b : setup.beams) {
        if (!list.empty()) list += ", ";
        list += rt::beam_text(b) + " at " + rt::point_text(b.isocentre_ct_mm);
      }
      return invalid_argument(where + ": the plan has " + std::to_string(distinct.size()) +
                              " isocentres: " + list + ": name one with --beam");
    }
  } else {
    int number = 0;
    const auto [ptr, ec] = std::from_chars(beam.data(), beam.data() + beam.size(), number);
    const bool is_number = ec == std::errc() && ptr == beam.data() + beam.size();
    std::vector<std::size_t> by_number, by_name;
    for (std::size_t i = 0; i < setup.beams.size(); ++i) {
      if (is_number && setup.beams[i].number == number) by_number.push_back(i);
      if (setup.beams[i].name == beam) by_name.push_back(i);
    }
    if (by_name.size() > 1 || (!by_number.empty() && !by_name.empty() && by_number != by_name))
      return invalid_argument(where + ": --beam '" + beam + "' names more than one beam (by number or by name): " +
                              rt::beam_list(setup.beams));
    chosen = by_number.empty() ? by_name : by_number;
    if (chosen.empty())
      return not_found(where + ": no beam '" + beam +
                       "' in the plan; its beams: " + rt::beam_list(setup.beams));
  }

  setup.beam = setup.beams[chosen.front()];
  for (std::size_t i : chosen) {
    auto position = rt::patient_position(plan, items.getItem(i), setup.beams[i], where);
    if (!position.ok()) return position.status();
    if (i == chosen.front()) {
      setup.patient_position = *position;
    } else if (*position != setup.patient_position) {
      return invalid_argument(where + ": " + rt::beam_text(setup.beam) + " (" + setup.patient_position +
                              ") and " + rt::beam_text(setup.beams[i]) + " (" + *position +
                              ") set the patient up differently: name one with --beam");
    }
  }
  // Every chosen beam's tolerance table bounds the couch: the tightest of each tolerance.
  for (std::size_t i : chosen) {
    auto t = rt::tolerances(plan, items.getItem(i), setup.beams[i], where);
    if (!t.ok()) return t.status();
    if (t->table_number == 0) continue;
    TableTopTolerances& all = setup.tolerances;
    if (std::find(all.table_numbers.begin(), all.table_numbers.end(), t->table_number) == all.table_numbers.end())
      all.table_numbers.push_back(t->table_number);
    if (all.table_number == 0) all.table_number = t->table_number;
    const auto tightest = [](std::optional<double>* into, const std::optional<double>& v) {
      if (v && (!*into || *v < **into)) *into = v;
    };
    tightest(&all.lateral_mm, t->lateral_mm);
    tightest(&all.longitudinal_mm, t->longitudinal_mm);
    tightest(&all.vertical_mm, t->vertical_mm);
    tightest(&all.pitch_deg, t->pitch_deg);
    tightest(&all.roll_deg, t->roll_deg);
    tightest(&all.patient_support_deg, t->patient_support_deg);
  }
  return setup;
}

}  // namespace lftrack::session
