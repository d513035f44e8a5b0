# mk/fuzz.mk — libFuzzer targets (clang, ASan+UBSan) for the parsers a stranger
# can reach: JSON control messages, binary frames, the config file, ..., and
# ocean-tap's readers of measured seas (text from any URL).
#
#   make fuzz                  run each target for FUZZ_SECONDS (default 60)
#   make fuzz FUZZ_SECONDS=600 a longer local run
# `make test` runs test-fuzz: every regression input once, then each target
# for FUZZ_CI_SECONDS (10 s each, under CI too: one per FUZZ_TARGETS entry, and
# make test must stay under 20 minutes on 2 cores; longer runs: make fuzz).

FUZZ_CC      := clang
FUZZ_FLAGS   := -std=c11 -D_GNU_SOURCE -g -O1 -fsanitize=fuzzer,address,undefined \
                -fno-sanitize-recover=all $(INC) -Iserver/sim $(WARN)
FUZZ_SECONDS ?= 60
FUZZ_CI_SECONDS ?= 10
FUZZ_TARGETS := control frame config
FUZZ_TARGETS += cluster
FUZZ_TARGETS += query
FUZZ_TARGETS += netwire
FUZZ_TARGETS += inflate
# The C library's grid assembler (oc_grid_*): frames from the network into per-cascade grids.
FUZZ_TARGETS += grid
# A measured sea (server/sim/sea_spectrum.c, sea_model.c): the validator, the directional
# reconstruction and the capture of whatever it accepts.
FUZZ_TARGETS += sea
# ocean-tap's readers of measured seas (tools/sea_*.c): text from any server a URL names.
FUZZ_TARGETS += sea_ndbc sea_ww3 sea_cdip
# The `sea` message's document (server/control/sea_msg.c): JSON into the library's sea and back.
FUZZ_TARGETS += sea_msg
# Floating bodies: launch/steer/remove/claim (body_msg.c) and the BODY section of a frame header.
FUZZ_TARGETS += bodies
FUZZ_TARGETS += cluster_bodies

# The config loader's input is JSON text: the operands of integer compares
# (trace-cmp) are parsed binary values that libFuzzer cannot splice back into
# text, while the key names still come from its strcmp hooks. Without
# trace-cmp an execution costs ~20 % less CPU and same-seed runs reach the
# same edges (docs/reliability.md, "Fuzzing").
FUZZ_FLAGS_config := -fno-sanitize-coverage=trace-cmp

SIM_SRCS_FOR_FUZZ = $(wildcard server/sim/*.c) server/common/pool.c
FUZZ_SRCS_control = fuzz/fuzz_control.c $(wildcard server/control/*.c) $(SIM_SRCS_FOR_FUZZ)
FUZZ_SRCS_frame   = fuzz/fuzz_frame.c $(wildcard proto/c/*.c)
FUZZ_SRCS_grid    = fuzz/fuzz_grid.c $(wildcard proto/c/*.c)
FUZZ_SRCS_config  = fuzz/fuzz_config.c $(wildcard server/config/*.c server/control/*.c server/base/*.c) \
                    $(SIM_SRCS_FOR_FUZZ)
FUZZ_SRCS_sea     = fuzz/fuzz_sea.c $(SIM_SRCS_FOR_FUZZ)
FUZZ_SRCS_sea_msg = fuzz/fuzz_sea_msg.c $(wildcard server/control/*.c) $(SIM_SRCS_FOR_FUZZ)
FUZZ_SRCS_bodies  = fuzz/fuzz_bodies.c $(wildcard server/control/*.c) $(wildcard proto/c/*.c) $(SIM_SRCS_FOR_FUZZ)
# What a cluster reads of the bodies: the edge's BODY_SECTION check, the record's "bodies".
FUZZ_SRCS_cluster_bodies = fuzz/fuzz_cluster_bodies.c server/roles/edge_bodies.c server/config/state_bodies.c \
                           server/base/fileio.c $(wildcard server/control/*.c) $(wildcard proto/c/*.c) \
                           $(SIM_SRCS_FOR_FUZZ)
FUZZ_SRCS_query   = fuzz/fuzz_query.c server/query/probe.c $(wildcard server/control/*.c) $(SIM_SRCS_FOR_FUZZ)
# cluster_*.c are the transport's NATS-free parts (formats, subjects, assembly,
# demand); link*.c talk to NATS and are not fuzzed here.
FUZZ_SRCS_cluster = fuzz/fuzz_cluster.c $(wildcard server/cluster/cluster_*.c) proto/c/oc_header.c
$(BUILD)/fuzz/fuzz_cluster: $(wildcard server/cluster/*.[ch])
FUZZ_SRCS_netwire = fuzz/fuzz_netwire.c server/net/upgrade.c server/base/metrics.c server/base/log.c
$(BUILD)/fuzz/fuzz_netwire: $(wildcard server/net/*.[ch])
# The web client's WebAssembly inflater (mk/wasm.mk), natively, against zlib.
FUZZ_SRCS_inflate = fuzz/fuzz_inflate.c proto/wasm/oc_inflate.c
FUZZ_FLAGS_inflate := -Iproto/wasm
$(BUILD)/fuzz/fuzz_inflate: $(wildcard proto/wasm/*.[ch])
FUZZ_SRCS_sea_ndbc = fuzz/fuzz_sea_ndbc.c tools/sea_ndbc.c tools/sea_doc.c
FUZZ_SRCS_sea_ww3  = fuzz/fuzz_sea_ww3.c tools/sea_ww3.c tools/sea_doc.c
FUZZ_SRCS_sea_cdip = fuzz/fuzz_sea_cdip.c tools/sea_cdip.c tools/sea_doc.c
FUZZ_FLAGS_sea_ndbc := -Itools
FUZZ_FLAGS_sea_ww3  := -Itools
FUZZ_FLAGS_sea_cdip := -Itools
$(BUILD)/fuzz/fuzz_sea_ndbc $(BUILD)/fuzz/fuzz_sea_ww3 $(BUILD)/fuzz/fuzz_sea_cdip: tools/sea.h tools/sea_doc.c
$(BUILD)/fuzz/fuzz_sea_ndbc: tools/sea_ndbc.c
$(BUILD)/fuzz/fuzz_sea_ww3: tools/sea_ww3.c
$(BUILD)/fuzz/fuzz_sea_cdip: tools/sea_cdip.c

$(BUILD)/fuzz/fuzz_%: fuzz/fuzz_%.c $(wildcard server/*/*.[ch] server/sim/include/*.h proto/c/*.c proto/c/*.h)
	@mkdir -p $(dir $@)
	$(FUZZ_CC) $(FUZZ_FLAGS) $(FUZZ_FLAGS_$*) $(PKG_CFLAGS) $(FUZZ_SRCS_$*) -o $@ $(PKG_LIBS) $(FUZZ_EXTRA_LIBS)

FUZZ_BINS := $(addprefix $(BUILD)/fuzz/fuzz_,$(FUZZ_TARGETS))

.PHONY: fuzz fuzz-build test-fuzz
fuzz-build: $(FUZZ_BINS)
fuzz: fuzz-build
	@for t in $(FUZZ_TARGETS); do fuzz/run.sh $(BUILD) $$t $(FUZZ_SECONDS) || exit 1; done
test-fuzz: fuzz-build
	@for t in $(FUZZ_TARGETS); do fuzz/run.sh $(BUILD) $$t $(FUZZ_CI_SECONDS) || exit 1; done
TESTS += test-fuzz
