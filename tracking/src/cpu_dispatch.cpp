// Every kernel family's choice of instruction set, from cpu_features() (cpu_features.hpp). The
// kernels' headers declare these; their files define only the kernels.

#include "lftrack/tracking/cpu_features.hpp"
#include "light_field_kernels.hpp"
#include "mutual_information_kernels.hpp"
#include "siddon_walk.hpp"

namespace lftrack::tracking {

const CpuFeatures& cpu_features() {
  static const CpuFeatures features = [] {
    CpuFeatures f;
#if defined(__x86_64__) && defined(__GNUC__)
    __builtin_cpu_init();
    f.sse42 = __builtin_cpu_supports("sse4.2") != 0;
    f.avx2 = __builtin_cpu_supports("avx2") != 0;
    f.fma = __builtin_cpu_supports("fma") != 0;
    f.avx512f = __builtin_cpu_supports("avx512f") != 0;
    f.avx512bw = __builtin_cpu_supports("avx512bw") != 0;
#endif
    return f;
  }();
  return features;
}

bool light_field_avx2_available() {
  return cpu_features().avx2 && cpu_features().fma;
}
bool light_field_avx512_available() {
  return cpu_features().avx512f && cpu_features().avx512bw;
}
bool mi_avx2_available() {
  return cpu_features().avx2;
}

namespace detail {
bool siddon_avx2_available() {
  return cpu_features().avx2;
}
bool siddon_avx512_available() {
  return cpu_features().avx512f;
}
}  // namespace detail

}  // namespace lftrack::tracking
