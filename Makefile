# oceand — top-level build. Each area keeps its rules in mk/<area>.mk and
# appends to BINS (built by `make`), TESTS (suites run by `make test`) and
# BENCHES (run by `make bench`).
#
#   make run    install what is missing, build, start the daemon + web client
#   make test   install what is missing, build, run every test suite

SHELL   := /bin/bash
BUILD   := build
CC      ?= cc
PKGS    := fftw3f libwebsockets libcjson libzstd zlib
WARN    := -Wall -Wextra -Werror -Wshadow -Wstrict-prototypes -Wno-unused-parameter
CFLAGS  ?= -O2 -g
CFLAGS  += -std=c11 -D_GNU_SOURCE $(WARN) -pthread
# Include paths are per folder so that dependencies run one way: a file
# that includes a header from a folder it may not depend on does not compile.
#   server/sim/ (the simulation library) sees only its own headers and common/;
#   proto/c/ (protocol + codec) sees only its own;
#   server/<folder>/ sees its own folder and those below it, in this order:
#   base (log, clock, metrics, files) and control (messages) -> config, query
#   -> tick -> net -> roles (+ cluster) -> main.c.
# server/common/ (the work pool, pool.h) is seen by the library and the
# daemon alike and sees nothing of either.
# Tools, tests and benchmarks see the daemon's folders and the library's
# public header folder server/sim/include; the library's own tests add
# server/sim (mk/sim.mk).
INC_base    := -Iserver/base
INC_control := -Iserver/control -Iserver/sim/include -Iproto/c
INC_config  := -Iserver/config $(INC_base) $(INC_control)
INC_query   := -Iserver/query $(INC_base) $(INC_control) -Iserver/common
INC_tick    := -Iserver/tick $(INC_query)
INC_net     := -Iserver/net $(INC_tick) -Iserver/config
INC_roles   := -Iserver/roles $(INC_net) -Iserver/cluster
INC         := $(INC_roles) -Iserver
$(foreach d,base control config query tick net roles,\
  $(eval $(BUILD)/obj/server/$(d)/%.o $(BUILD)/san/server/$(d)/%.o: INC := $$(INC_$(d))))
$(BUILD)/obj/server/sim/%.o $(BUILD)/san/server/sim/%.o: INC := -Iserver/sim/include -Iserver/sim -Iserver/common
$(BUILD)/obj/proto/c/%.o $(BUILD)/san/proto/c/%.o: INC := -Iproto/c
PKG_CFLAGS = $(shell pkg-config --cflags $(PKGS) 2>/dev/null)
PKG_LIBS   = $(shell pkg-config --libs $(PKGS) 2>/dev/null) -lfftw3f_threads -lm
# Sanitizer flavour of every C object, for the ASan+UBSan test pass.
SAN_FLAGS := -O1 -g -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=all

BINS    :=
TESTS   :=
BENCHES :=

.PHONY: all deps test bench run clean
all: deps
	@$(MAKE) --no-print-directory build-all

include $(sort $(wildcard mk/*.mk))

.PHONY: build-all
build-all: $(BINS)

deps:
	@scripts/deps.sh

# Every suite runs even if one fails; the closing line counts suites.
# First everything is built in parallel (build-all, then test-bins), so that the suites
# below do not compile their sanitizer/fuzz/TSan flavours one file at a time.
# Then tests/run_suites.sh runs them in three phases: the suites that mostly
# wait (real daemons on loopback at 30 Hz, NATS restarts: wall time >> CPU
# time) all at once, each into its own log (free ports, own temp dirs); the
# single-threaded CPU-bound ones that time nothing (valgrind, fuzzing, the
# libraries' sanitizer builds, the cluster's unit tests) one per core, the longest first; the others one
# at a time, alone on the machine: daemons that must keep their tick (ASan),
# the hostile battery (it measures the observer's share of frames; it runs its
# light cases 2 at a time itself), the link lab, SwiftShader.
TESTS_CONCURRENT := test-cluster-roles test-daemon test-tap test-ops test-python test-blender test-cluster-durable \
                    test-cluster-bodies
TESTS_PAIRED     := test-fuzz test-proto-valgrind test-sim-asan test-query-valgrind test-sim-valgrind \
                    test-daemon-valgrind test-sim test-cluster-valgrind test-proto-asan test-query \
                    test-cluster test-proto test-proto-js test-sim-tsan test-query-asan test-layout test-wording \
                    test-bodies test-bodies-asan test-bodies-valgrind \
                    test-sea test-sea-asan test-sea-valgrind test-sea-readers \
                    test-wakes test-wakes-asan test-wakes-valgrind
TEST_LOGS        := $(BUILD)/test-logs
test: deps
	@$(MAKE) --no-print-directory -j$$(nproc) build-all
	@$(MAKE) --no-print-directory -k -j$$(nproc) test-bins >$(BUILD)/test-bins.log 2>&1 || \
	  echo "test-bins: some test binaries did not build (their suites report it; log: $(BUILD)/test-bins.log)"
	@MAKE="$(MAKE)" tests/run_suites.sh $(TEST_LOGS) "$(filter $(TESTS_CONCURRENT),$(TESTS))" \
	  "$(filter $(TESTS),$(TESTS_PAIRED))" "$(filter-out $(TESTS_CONCURRENT) $(TESTS_PAIRED),$(TESTS))"

# Every binary a suite runs that build-all does not make (sanitizer, TSan and
# fuzz flavours, test helpers). One missing here is still built by its suite.
TEST_BINS = $(DAEMON_TEST_DEPS) $(FUZZ_BINS) $(BUILD)/tsan/test_ocean \
            $(addprefix $(BUILD)/san/,oceand test_control test_cluster_msg test_cluster_nats test_proto test_ocean test_query test_bodies test_sea test_wakes)
.PHONY: test-bins
test-bins: $(TEST_BINS)

bench: deps
	@$(MAKE) --no-print-directory build-all
	@for b in $(BENCHES); do $(MAKE) --no-print-directory $$b || exit 1; done

# One object rule for every C file in the tree: normal and sanitizer flavours.
$(BUILD)/obj/%.o: %.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(INC) $(PKG_CFLAGS) -MMD -MP -c $< -o $@
$(BUILD)/san/%.o: %.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(SAN_FLAGS) $(INC) $(PKG_CFLAGS) -MMD -MP -c $< -o $@
-include $(shell find $(BUILD) -name '*.d' 2>/dev/null)

clean:
	rm -rf $(BUILD)
