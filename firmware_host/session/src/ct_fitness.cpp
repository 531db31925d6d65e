// Whether a CT is fit for tracking and for the simulator's frames (patient_setup.hpp): its slices
// and pixels, the ROI's distance to the scan's edges, metal near the ROI.

#include <fmt/format.h>

#include <algorithm>
#include <iomanip>
#include <sstream>

#include "lftrack/session/patient_setup.hpp"

namespace lftrack::session {

using Eigen::Vector3d;

std::vector<std::string> ct_fitness_warnings(const tracking::CtVolume& ct, const Vector3d& isocentre_ct_mm,
                                             const Vector3d& roi_centre_ct_mm, const Vector3d& roi_size_mm) {
  std::vector<std::string> out;
  const tracking::VolumeGeometry& g = ct.geometry;
  std::ostringstream m;
  m << std::fixed << std::setprecision(2);
  const double slice = g.spacing_mm.z(), pixel = std::max(g.spacing_mm.x(), g.spacing_mm.y());
  if (slice > 2.0) {
    m << "the CT's slices are " << slice
      << " mm apart (radiosurgery plans on 1-1.5 mm): its DRRs are blurred along the "
      << "slices' normal, and the simulator draws its frames from the same CT, so the accuracy it reports is "
         "optimistic for this patient";
    out.push_back(m.str());
    m.str("");
  }
  if (pixel > 1.2) {
    m << "the CT's pixels are " << pixel
      << " mm (radiosurgery plans on 1 mm or finer): fine bone edges are lost in "
      << "the DRRs, and the simulator's frames share the loss, so the accuracy it reports is optimistic";
    out.push_back(m.str());
    m.str("");
  }
  // The ROI box (axis-aligned in the CT frame) in index space: its distance to the volume's edges.
  const Eigen::Affine3d index_from_ct = g.index_from_ct();
  Vector3d lo = Vector3d::Constant(1e300), hi = Vector3d::Constant(-1e300);
  for (int corner = 0; corner < 8; ++corner) {
    const Vector3d c =
        roi_centre_ct_mm + 0.5 * Vector3d((corner & 1) ? 1 : -1, (corner & 2) ? 1 : -1, (corner & 4) ? 1 : -1)
                                     .cwiseProduct(roi_size_mm);
    const Vector3d index = index_from_ct * c;
    lo = lo.cwiseMin(index);
    hi = hi.cwiseMax(index);
  }
  const char* axis_names[] = {"i (columns)", "j (rows)", "k (slices)"};
  for (int a = 0; a < 3; ++a) {
    const double below_mm = (lo[a] + 0.5) * g.spacing_mm[a],
                 above_mm = (g.size[a] - 0.5 - hi[a]) * g.spacing_mm[a];
    const double nearest = std::min(below_mm, above_mm);
    if (nearest < 0) {
      m << "the ROI reaches " << -nearest << " mm beyond the CT along its " << axis_names[a]
        << " axis: the DRRs see air where the frames see the patient";
      out.push_back(m.str());
      m.str("");
    } else if (nearest < 10) {
      m << "the ROI is " << nearest << " mm from the CT's edge along its " << axis_names[a]
        << " axis: anatomy the X-rays cross beyond the scan is missing from every DRR";
      out.push_back(m.str());
      m.str("");
    }
  }
  // Metal within 20 mm of the ROI: it streaks the CT and dominates both views.
  constexpr double kMetalHu = 2500, kNearMm = 20;
  std::int64_t metal = 0;
  float hottest = -1e9f;
  Vector3d hottest_ct = Vector3d::Zero();
  const Vector3d pad(kNearMm / g.spacing_mm.x(), kNearMm / g.spacing_mm.y(), kNearMm / g.spacing_mm.z());
  const Eigen::Vector3i i0 = (lo - pad).array().floor().cast<int>().max(0).matrix();
  const Eigen::Vector3i i1 = (hi + pad).array().ceil().cast<int>().min((g.size.array() - 1)).matrix();
  for (int k = i0.z(); k <= i1.z(); ++k)
    for (int j = i0.y(); j <= i1.y(); ++j)
      for (int i = i0.x(); i <= i1.x(); ++i) {
        const float hu = ct.at(i, j, k);
        if (hu < kMetalHu) continue;
        ++metal;
        if (hu > hottest) {
          hottest = hu;
          hottest_ct = g.ct_from_index() * Vector3d(i, j, k);
        }
      }
  if (metal > 0) {
    m << metal << " voxels above " << kMetalHu << " HU within " << kNearMm << " mm of the ROI (the densest "
      << std::setprecision(0) << hottest << " HU at " << std::setprecision(1)
      << fmt::format("({:.1f}, {:.1f}, {:.1f})", hottest_ct.x(), hottest_ct.y(), hottest_ct.z())
      << " mm): metal or dense contrast streaks the CT and dominates both views; look at the set-up picture, "
         "and keep it out of the ROI where it is not the target";
    out.push_back(m.str());
    m.str("");
  }
  (void)isocentre_ct_mm;
  return out;
}

std::string simulated_accuracy_caveat(const tracking::CtVolume& ct) {
  const Vector3d& s = ct.geometry.spacing_mm;
  if (!(s.z() > 2.0 || std::max(s.x(), s.y()) > 1.2)) return {};
  std::ostringstream m;
  m << std::fixed << std::setprecision(2) << "the CT's voxels are " << s.x() << " x " << s.y() << " x "
    << s.z()
    << " mm and the simulated frames are drawn from the same CT: this accuracy is optimistic for a patient "
       "(radiosurgery plans on 1-1.5 mm slices)";
  return m.str();
}

}  // namespace lftrack::session
