#pragma once
// Run-time CPU dispatch for hot kernels. The project compiles for baseline x86-64 so the binary
// runs on any x86-64 CPU; a function marked LFTRACK_HOT_CLONES is compiled again for AVX2+FMA
// (x86-64-v3) and the loader picks the best clone for the CPU it runs on (GCC target_clones,
// resolved once through an ifunc). Elsewhere the macro is empty, and so it is under
// ThreadSanitizer: gcc instruments the ifunc resolver, which the loader runs before the TSan
// runtime is up, and every test program then crashed while loading (make check-tsan).

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__) && \
    !defined(__SANITIZE_THREAD__)
#define LFTRACK_HOT_CLONES __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define LFTRACK_HOT_CLONES
#endif
