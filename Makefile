# arbor - build, test, run, bench.
#
#   make            build build/arbord (installs missing dependencies first)
#   make run        start the daemon on models/ and print the URL to open
#   make loadtest   wrk against a daemon (not part of make test)
#   make cluster    N daemons behind nginx on this machine (N=4 THREADS=1 PORT=8080)
#   make test       every test; last line "N passed, M failed, K skipped"
#   make models     regenerate the procedural models in models/ (SIZE=large for big ones)
#   make bench      the benchmark tables of docs/BENCH.md
#   make bench-embree   the same with Intel Embree side by side (EMBREE_ISA=avx2: Embree's
#                       kernels at most AVX2, as arbor's are, on a CPU with AVX-512)
#   make test SAN=address,undefined   the same under sanitizers (also SAN=thread), in build/san-*
#   make asan       alias of make test SAN=address,undefined
#   make fuzz       the libFuzzer targets of tests/fuzz for FUZZ_SECONDS each (clang)
#   make lint       cppcheck and clang-tidy on src/ (tests/lint)
#
# MARCH=-march=native by default; override with MARCH= for a portable build.

CC      ?= cc
MARCH   ?= -march=native
CFLAGS  ?=
SHARED  ?= $(abspath ../shared)

# SAN=address,undefined or SAN=thread: everything (library, arbord, tests) is
# built with those sanitizers in a folder of its own, build/san-address-undefined
# or build/san-thread, and make test runs every suite against that arbord. Any
# report fails the run: UBSan does not recover, and the runtimes halt on the
# first error (SAN_ENV below; the suites also look for reports in the daemon's
# stderr). Suppressions, each with its reason, would go in tests/san/.
comma   := ,
ifneq ($(SAN),)
BUILD   ?= build/san-$(subst $(comma),-,$(SAN))
OPT     ?= -O1 -g -fno-omit-frame-pointer
SANFLAGS ?= -fsanitize=$(SAN) -fno-sanitize-recover=all
# Brute force is the tests' oracle, O(rays x triangles): instrumented, it
# is most of a sanitizer run's time (test_accel under ASan: 13 minutes, 3
# with brute force uninstrumented), and its loop only reads a validated mesh
# and writes the caller's answers. It is built as in the plain run so the
# sanitizers spend their time on the trees and the daemon
# (docs/RELIABILITY.md).
$(BUILD)/obj/src/geom/brute.o: OPT = -O2 -g -fno-omit-frame-pointer
$(BUILD)/obj/src/geom/brute.o: SANFLAGS =
endif
OPT     ?= -O2
BUILD   ?= build
SANFLAGS ?=
SAN_ENV = ASAN_OPTIONS=halt_on_error=1:detect_leaks=1:detect_stack_use_after_return=1:strict_string_checks=1 \
          UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 \
          TSAN_OPTIONS=halt_on_error=1:second_deadlock_stack=1

# Embree is optional: compiled in when its header is installed (make bench-embree installs it).
# Not under TSan: Embree's worker threads synchronise in its own uninstrumented
# code (TBB), so TSan reports races inside every Embree build that it cannot
# judge; there the suites take their "built without Embree" paths, and ASan
# watches the Embree jobs.
ifneq ($(filter thread,$(SAN)),)
EMBREE  :=
endif
EMBREE  ?= $(shell test -f /usr/include/embree3/rtcore.h && echo 1)

# -ffp-contract=off: no compiler may fuse a * b + c into one FMA on its own.
# The builders and validators, brute force and the SIMD triangle tests rely on
# the same expression rounding the same way wherever it is written (gcc in ISO
# C mode never fuses; clang does by default, and its fuzz build then found a k-d
# leaf whose clipped box and the validator's disagreed at 1e7 from the origin).
ARBOR_CFLAGS = -std=c11 -Wall -Wextra -Werror $(OPT) $(SANFLAGS) $(MARCH) -ffp-contract=off -D_POSIX_C_SOURCE=200809L \
               -Iinclude -MMD -MP -pthread $(CFLAGS)
LDLIBS  = -lmicrohttpd -lcjson -lpng -lz -lpthread -lm
ifeq ($(EMBREE),1)
ARBOR_CFLAGS += -DARBOR_HAVE_EMBREE
LDLIBS  += -lembree3
endif

LIB_SRC  = $(wildcard src/core/*.c src/geom/*.c src/accel/*.c src/render/*.c src/bench/*.c src/store/*.c src/server/*.c)
CLI_SRC  = $(wildcard src/cli/*.c)
TEST_SRC = $(wildcard tests/unit/test_*.c)
# Traversal kernels (src/accel/accel_impl.h): every source of KERNEL_SRC is
# compiled once per kernel of KERNELS, with -DACCEL_KERNEL=<kernel> and the
# kernel's instruction set, into <source>.<kernel>.o; accel.c picks one at
# run time, so even a portable build (MARCH=) traces with AVX2 where the CPU
# has it. The sse2 kernel turns AVX off even under -march=native, so that it
# is what a CPU without AVX runs (and the tests can compare the two).
# -Wno-psabi: without AVX GCC notes that 8-lane vectors would be passed
# differently across calls; the kernels' vector helpers are all inlined.
KERNEL_SRC = src/accel/bvh_traverse.c src/accel/kd_traverse.c
KERNELS    = sse2 avx2
KERNEL_CFLAGS_sse2 = -mno-avx -Wno-psabi
KERNEL_CFLAGS_avx2 = -mavx2 -mfma
LIB_SRC := $(filter-out $(KERNEL_SRC),$(LIB_SRC))
LIB_OBJ  = $(LIB_SRC:%.c=$(BUILD)/obj/%.o) $(foreach k,$(KERNELS),$(KERNEL_SRC:%.c=$(BUILD)/obj/%.$(k).o))
CLI_OBJ  = $(CLI_SRC:%.c=$(BUILD)/obj/%.o)
TEST_BIN = $(TEST_SRC:tests/unit/%.c=$(BUILD)/tests/%)
UNITY    = build/deps/unity/src
TEST_SUPPORT_OBJ = $(BUILD)/obj/tests/unit/support.o $(BUILD)/obj/unity.o

.PHONY: all deps run test unit models bench bench-embree asan fuzz lint loadtest cluster soak clean
# Keep intermediate objects: deleting them would also print "rm ..." after the
# test summary, which must stay the last line of make test.
.SECONDARY:
.DEFAULT_GOAL := all

all: $(BUILD)/arbord

# Quick and silent when everything is installed; installs what is missing.
deps:
	@scripts/deps.sh
	@scripts/deps-e2e.sh

$(BUILD)/obj/%.o: %.c | deps
	@mkdir -p $(dir $@)
	$(CC) $(ARBOR_CFLAGS) -c $< -o $@

define KERNEL_RULE
$(BUILD)/obj/%.$(1).o: %.c | deps
	@mkdir -p $$(dir $$@)
	$$(CC) $$(ARBOR_CFLAGS) $$(KERNEL_CFLAGS_$(1)) -DACCEL_KERNEL=$(1) -c $$< -o $$@
endef
$(foreach k,$(KERNELS),$(eval $(call KERNEL_RULE,$(k))))

$(BUILD)/libarbor.a: $(LIB_OBJ)
	@rm -f $@
	ar rcs $@ $^

$(BUILD)/arbord: $(CLI_OBJ) $(BUILD)/libarbor.a
	$(CC) $(ARBOR_CFLAGS) -o $@ $(CLI_OBJ) $(BUILD)/libarbor.a $(LDLIBS)

$(BUILD)/obj/unity.o: | deps
	@mkdir -p $(dir $@)
	$(CC) -std=c11 $(OPT) -c $(UNITY)/unity.c -o $@

$(BUILD)/obj/tests/unit/%.o: tests/unit/%.c | deps
	@mkdir -p $(dir $@)
	$(CC) $(ARBOR_CFLAGS) -I$(UNITY) -Itests/unit -c $< -o $@

$(BUILD)/tests/%: $(BUILD)/obj/tests/unit/%.o $(TEST_SUPPORT_OBJ) $(BUILD)/libarbor.a
	@mkdir -p $(dir $@)
	$(CC) $(ARBOR_CFLAGS) -o $@ $^ $(LDLIBS)

# test_alloc_fail alone links the allocator that fails on demand (it defines
# malloc for the whole process); dlsym finds the allocator it wraps.
$(BUILD)/tests/test_alloc_fail: $(BUILD)/obj/tests/unit/alloc_hook.o
$(BUILD)/tests/test_alloc_fail: LDLIBS += -ldl

# The fuzz targets of tests/fuzz. Linked with replay.c they are test programs
# that replay the target's committed corpus (every regression input) in every
# build, gcc and sanitizers included; make fuzz builds them with clang as
# libFuzzer fuzzers.
FUZZ_TARGETS = obj ply render_request upload static trees
FUZZ_REPLAY  = $(FUZZ_TARGETS:%=$(BUILD)/tests/fuzz_%)
TEST_BIN    += $(FUZZ_REPLAY)

$(BUILD)/obj/tests/fuzz/%.o: tests/fuzz/%.c | deps
	@mkdir -p $(dir $@)
	$(CC) $(ARBOR_CFLAGS) -c $< -o $@

$(BUILD)/obj/tests/fuzz/replay_%.o: tests/fuzz/replay.c | deps
	@mkdir -p $(dir $@)
	$(CC) $(ARBOR_CFLAGS) -DFUZZ_CORPUS='"tests/fuzz/corpus/$*"' -c $< -o $@

$(BUILD)/tests/fuzz_%: $(BUILD)/obj/tests/fuzz/fuzz_%.o $(BUILD)/obj/tests/fuzz/replay_%.o \
                       $(BUILD)/obj/tests/fuzz/fuzz.o $(BUILD)/libarbor.a
	@mkdir -p $(dir $@)
	$(CC) $(ARBOR_CFLAGS) -o $@ $^ $(LDLIBS)

$(BUILD)/fuzzers/fuzz_%: $(BUILD)/obj/tests/fuzz/fuzz_%.o $(BUILD)/obj/tests/fuzz/fuzz.o $(BUILD)/libarbor.a
	@mkdir -p $(dir $@)
	$(CC) $(ARBOR_CFLAGS) -fsanitize=fuzzer -o $@ $^ $(LDLIBS)

unit: $(TEST_BIN)

# Unity binaries, then the suites that drive the real binary: the CLI, the
# daemon over HTTP, the viewer in Chromium. Each prints Unity's summary line;
# tests/run.sh sums them into the one last line.
SUITES = tests/cli/run.sh tests/http/run.py tests/e2e/run.sh tests/cluster/run.py

# Under TSan (many times slower) the run leaves out what costs most and
# races least, so that .ci/run stays within its time: test_accel's
# brute-force comparison of every tree on the real models (builds on pools
# and their cancelling are also in test_pool and test_store, which run) and
# the browser suite (the HTTP suite drives the same daemon threads). It says
# so before the summary; ASan and the plain run keep everything.
# The single-threaded suites of the geometry and the builders (loaders, k-d
# and BVH builds, procedural models, bench figures, exactness against brute
# force, both kernels) have no threads for TSan to watch beyond the pool's,
# and cost it minutes each (test_exact about 10), so they run in the plain
# and ASan runs only.
TSAN_LEAVE_OUT = $(addprefix $(BUILD)/tests/,test_accel test_kd test_bvh test_bench test_procgen test_load \
                   test_exact test_kernels) \
                 tests/e2e/run.sh
# test_alloc_fail runs under ASan, whose allocator its own forwards to, so
# LeakSanitizer sees every block a failed operation left behind. TSan leaves
# it out with the single-threaded suites: the server part's few threads are
# the same as test_store's and the HTTP suite's, which TSan watches.
SAN_LEAVE_OUT = $(if $(filter thread,$(SAN)),$(TSAN_LEAVE_OUT) $(BUILD)/tests/test_alloc_fail)
TEST_RUN = $(if $(SAN),$(filter-out $(SAN_LEAVE_OUT),$(TEST_BIN) $(SUITES)),$(TEST_BIN) $(SUITES))

# Unity binaries run this many at a time (tests/run.sh); the suites one at a time.
TEST_JOBS ?= $(shell nproc 2>/dev/null || echo 1)
test: $(BUILD)/arbord $(TEST_BIN)
	@$(if $(SAN),echo "SAN=$(SAN) leaves out: $(SAN_LEAVE_OUT) (see the Makefile)")
	@$(SAN_ENV) ARBORD=$(abspath $(BUILD)/arbord) ARBOR_SHARED_MODELS=$(SHARED)/models ARBOR_TEST_JOBS=$(TEST_JOBS) tests/run.sh $(TEST_RUN)

# The daemon on the repository's models/ and web/ (PORT=8080 by default); Ctrl-C stops it.
PORT ?= 8080
run: $(BUILD)/arbord
	@echo "arbord: open http://127.0.0.1:$(PORT)/ (Ctrl-C stops it)"
	@exec $(BUILD)/arbord serve --port $(PORT)

# N daemons, each a host in a network namespace of its own (loopback ports where
# namespaces are not allowed), behind Debian's nginx at PORT; Ctrl-C stops them all
# (deploy/cluster.sh, docs/SCALE.md).
N ?= 4
THREADS ?= 1
cluster: $(BUILD)/arbord
	@ARBORD=$(abspath $(BUILD)/arbord) exec deploy/cluster.sh -n $(N) --port $(PORT) --threads $(THREADS)

# wrk against a daemon of its own (tests/load/run.sh; LOAD_SECONDS=30 by default).
loadtest: $(BUILD)/arbord
	@ARBORD=$(abspath $(BUILD)/arbord) tests/load/run.sh

# One daemon under mixed load for SOAK_SECONDS (600) with a report each minute (tests/soak/run.py;
# not part of make test).
soak: $(BUILD)/arbord
	@ARBORD=$(abspath $(BUILD)/arbord) tests/soak/run.py

# The small models are committed in models/; SIZE=large writes multi-million-triangle
# versions to build/models-large instead (never committed, not rendered by make run).
models: $(BUILD)/arbord
	@mkdir -p $(BUILD)/models-large
	$(BUILD)/arbord gen --all $(if $(SIZE),--size $(SIZE) --dir $(BUILD)/models-large,--dir models)

# The figures of docs/BENCH.md (raw output and tables in build/bench/).
bench: $(BUILD)/arbord
	SHARED=$(SHARED) scripts/bench.sh

# The objects that test ARBOR_HAVE_EMBREE are rebuilt, in case arbord was built before Embree was installed.
# The archive goes too: under .SECONDARY make remakes a missing object only for a target it must remake anyway.
bench-embree:
	@scripts/deps.sh --embree
	rm -f $(BUILD)/obj/src/bench/embree_peer.o $(BUILD)/libarbor.a $(BUILD)/arbord
	$(MAKE) EMBREE=1 $(BUILD)/arbord
	SHARED=$(SHARED) scripts/bench.sh $(if $(EMBREE_ISA),--embree-isa $(EMBREE_ISA),--embree)

asan:
	@$(MAKE) --no-print-directory SAN=address,undefined test

# libFuzzer (clang, installed by scripts/deps.sh --fuzz): every target of
# FUZZ_TARGETS under ASan and UBSan in build/fuzz, FUZZ_SECONDS each, from
# its seed corpus tests/fuzz/corpus/<target> (tests/fuzz/run.sh), FUZZ_JOBS
# targets at a time.
FUZZ_SECONDS ?= 60
FUZZ_JOBS ?= $(shell nproc 2>/dev/null || echo 1)
fuzz:
	@scripts/deps.sh --fuzz
	@$(MAKE) --no-print-directory CC=clang BUILD=build/fuzz OPT="-O1 -g -fno-omit-frame-pointer" \
	    SANFLAGS="-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all" \
	    $(FUZZ_TARGETS:%=build/fuzz/fuzzers/fuzz_%)
	@ARBOR_FUZZ_JOBS=$(FUZZ_JOBS) tests/fuzz/run.sh $(FUZZ_SECONDS) build/fuzz $(FUZZ_TARGETS)

# cppcheck and clang-tidy on src/ (installed by scripts/deps.sh --lint); the
# checks and why are in tests/lint/run.sh and .clang-tidy.
lint:
	@scripts/deps.sh --lint
	@tests/lint/run.sh

clean:
	rm -rf $(BUILD)/obj $(BUILD)/tests $(BUILD)/arbord $(BUILD)/libarbor.a

-include $(shell find $(BUILD)/obj -name '*.d' 2>/dev/null)
