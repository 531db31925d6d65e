#pragma once
// What this CPU runs, asked once: the one place in the project's code that asks (issue 55, one
// place per choice; GCC's target_clones resolvers, cpu_dispatch.hpp, ask for themselves). The kernel families
// choose from it in tracking/src/cpu_dispatch.cpp, which holds every family's rule (light fields:
// AVX-512F+BW, AVX2+FMA, portable; the Siddon walk: AVX-512F, AVX2, portable; mutual information's lanes:
// AVX2, portable); the journal's CRC32C takes SSE4.2 from here; a phantom cache's fingerprint names FMA (it
// changes the phantom's last bits). The kernels' own files hold only their code.
//
// A build that is not x86-64 GCC or Clang compiles no x86 kernel: every feature reads false there
// and the portable code runs.

namespace lftrack::tracking {

struct CpuFeatures {
  bool sse42 = false;
  bool avx2 = false;
  bool fma = false;
  bool avx512f = false;
  bool avx512bw = false;
};

const CpuFeatures& cpu_features();

}  // namespace lftrack::tracking
