# The README's two commands, and the steps they are made of.
#   make demo   install what is missing, build, run the closed loop on the default scene
#   make check  install what is missing, build, run the fast tier of the tests (check-full: all)
BUILD_DIR ?= build
BUILD_TYPE ?= Release
JOBS ?= $(shell nproc)
LFTRACK := $(BUILD_DIR)/bin/lftrack

.PHONY: all setup configure build demo deb check check-slow check-full check-asan check-tsan check-sanitized fuzz-build bench fuzz clean

all: build

setup:
	@bash scripts/setup.sh

configure: setup
	@cmake -S . -B $(BUILD_DIR) -G Ninja -DCMAKE_BUILD_TYPE=$(BUILD_TYPE) -DLFTRACK_WERROR=ON >/dev/null

build: configure
	@cmake --build $(BUILD_DIR) -j $(JOBS)

demo: build
	@$(LFTRACK) sim --scene builtin:phantom --cycles 300

# The Debian package (issue 59) of the build `make check` tests: out/deb/lftrack_VERSION_amd64.deb,
# checked by lintian (scripts/make-deb.sh; the README's "In the clinic").
deb: build
	@bash scripts/make-deb.sh $(BUILD_DIR) out/deb

# Test tiers (issue 54; tests/CMakeLists.txt labels each test): `check` runs the fast tier (unit,
# cross-implementation, protocol and simulated-clock closed-loop tests); `check-slow` the slow and
# real-clock tiers (studies, soaks, devices in other processes, the browser); `check-full` both.
check: build
	@cd $(BUILD_DIR) && ctest --output-on-failure -j $(JOBS) --timeout 900 -L '^fast$$'
check-slow: build
	@cd $(BUILD_DIR) && ctest --output-on-failure -j $(JOBS) --timeout 900 -L '^(slow|realclock)$$'
check-full: build
	@cd $(BUILD_DIR) && ctest --output-on-failure -j $(JOBS) --timeout 900

# The suite under sanitizers (issue 23), each in a build folder of its own: AddressSanitizer with
# UndefinedBehaviorSanitizer, and ThreadSanitizer (the loop's journal, archive, replay and
# operator threads; the thread pool). SANITIZE_TESTS narrows the run (a ctest -R regex).
SANITIZE_TESTS ?= .
check-asan: setup
	@cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DLFTRACK_BUILD_BENCH=OFF \
	    -DCMAKE_CXX_FLAGS="-fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer" >/dev/null
	@cmake --build build-asan -j $(JOBS)
	@cd build-asan && ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 \
	    ctest --output-on-failure -j $(JOBS) --timeout 1800 -R '$(SANITIZE_TESTS)'
check-tsan: setup
	@cmake -S . -B build-tsan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DLFTRACK_BUILD_BENCH=OFF \
	    -DCMAKE_CXX_FLAGS="-fsanitize=thread -fno-omit-frame-pointer" >/dev/null
	@cmake --build build-tsan -j $(JOBS)
	@cd build-tsan && TSAN_OPTIONS="halt_on_error=1 suppressions=$(CURDIR)/tests/tsan.supp" ctest --output-on-failure -j $(JOBS) --timeout 1800 -R '$(SANITIZE_TESTS)'

# Fuzzing (issue 23): every fuzz target built with clang, libFuzzer, ASan and UBSan in
# build-fuzz/, seeded from valid files, run FUZZ_SECONDS each; report in out/fuzz/report.md.
# The same build folder holds the unit and protocol test suites compiled the same way (clang,
# ASan, UBSan), for check-sanitized.
FUZZ_SECONDS ?= 60
fuzz-build: setup
	@bash scripts/setup.sh --fuzz
	@CC=clang CXX=clang++ cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DLFTRACK_FUZZ=ON \
	    -DLFTRACK_BUILD_TESTS=ON -DLFTRACK_BUILD_BENCH=OFF >/dev/null
	@cmake --build build-fuzz -j $(JOBS) --target lftrack_fuzzers lftrack_sanitized_suites
fuzz: build fuzz-build
	@bash scripts/fuzz-seeds.sh $(LFTRACK)
	@bash scripts/fuzz-run.sh $(FUZZ_SECONDS) build-fuzz $(JOBS)

# What CI runs after `make check` (issue 23): the unit and protocol suites under ASan and UBSan,
# then every fuzz target for CI_FUZZ_SECONDS on its seeds. Fails on any test failure, sanitizer
# report, fuzzer crash, leak or timeout. The suites run as whole programs cut into shards (ctest
# label `sanitized`, tests/CMakeLists.txt: a sanitized program takes about 0.4 s to start, one
# process per test doubled the time), without the slowest single-threaded numeric tests
# (LFTRACK_SANITIZED_SKIP, 10-30 s each under ASan); `make check-asan` runs them. One test alone:
# `cd build-fuzz && ctest -R Suite.Test`.
CI_FUZZ_SECONDS ?= 10
check-sanitized: build fuzz-build
	@cd build-fuzz && ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 \
	    ctest --output-on-failure -j $(JOBS) --timeout 900 -L '^sanitized$$'
	@bash scripts/fuzz-seeds.sh $(LFTRACK)
	@bash scripts/fuzz-run.sh $(CI_FUZZ_SECONDS) build-fuzz $(JOBS)

bench: build
	@$(LFTRACK) bench drr --size 256

clean:
	rm -rf $(BUILD_DIR) build-fuzz build-asan build-tsan out
