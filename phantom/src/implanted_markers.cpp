#include "lftrack/phantom/implanted_markers.hpp"

#include <algorithm>
#include <cmath>

namespace lftrack::phantom {

using tracking::AttenuationPerMm;
using tracking::HounsfieldUnits;
using tracking::ScalarVolume;
using tracking::VolumeGeometry;

template <class Unit>
void insert_markers(ScalarVolume<Unit>* volume, const std::vector<Eigen::Vector3d>& centres, double radius_mm,
                    float marker_value) {
  const VolumeGeometry& g = volume->geometry;
  const Eigen::Affine3d index_from_ct = g.index_from_ct();
  const Eigen::Affine3d ct_from_index = g.ct_from_index();
  constexpr int kSub = 4;
  for (const Eigen::Vector3d& centre : centres) {
    const Eigen::Vector3d ci = index_from_ct * centre;
    const Eigen::Vector3d reach =
        (radius_mm + 1e-9) * g.spacing_mm.cwiseInverse() + Eigen::Vector3d::Constant(1);
    Eigen::Vector3i lo, hi;
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::max(0, int(std::floor(ci[a] - reach[a])));
      hi[a] = std::min(g.size[a] - 1, int(std::ceil(ci[a] + reach[a])));
    }
    for (int k = lo.z(); k <= hi.z(); ++k)
      for (int j = lo.y(); j <= hi.y(); ++j)
        for (int i = lo.x(); i <= hi.x(); ++i) {
          int inside = 0;
          for (int a = 0; a < kSub; ++a)
            for (int b = 0; b < kSub; ++b)
              for (int c = 0; c < kSub; ++c) {
                const Eigen::Vector3d sub(i + (a + 0.5) / kSub - 0.5, j + (b + 0.5) / kSub - 0.5,
                                          k + (c + 0.5) / kSub - 0.5);
                if ((ct_from_index * sub - centre).norm() <= radius_mm) ++inside;
              }
          if (inside == 0) continue;
          const float share = float(inside) / float(kSub * kSub * kSub);
          float& v = volume->at(i, j, k);
          v = (1 - share) * v + share * marker_value;
        }
  }
}

template void insert_markers(ScalarVolume<HounsfieldUnits>*, const std::vector<Eigen::Vector3d>&, double,
                             float);
template void insert_markers(ScalarVolume<AttenuationPerMm>*, const std::vector<Eigen::Vector3d>&, double,
                             float);

}  // namespace lftrack::phantom
