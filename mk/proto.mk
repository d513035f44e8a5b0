# mk/proto.mk — wire protocol and tile codec (proto/). See proto/PROTOCOL.md.
#   make build/liboc_proto.a   the library (and build/san/liboc_proto.a)
#   make test-proto            C decoder/encoder tests + the Python reference decoder on the vectors
#   make test-proto-asan       the C tests under ASan+UBSan
#   make test-proto-valgrind   the C tests under valgrind (errors and definite leaks fail)
#   make test-proto-js         the JavaScript decoder (node --test)
#   make proto-vectors         regenerate proto/vectors/ (checked in)
#   make bench-codec           codec benchmark, JSON lines

PROTO_SRCS     := $(sort $(wildcard proto/c/*.c))
PROTO_LIB      := $(BUILD)/liboc_proto.a
PROTO_SAN_LIB  := $(BUILD)/san/liboc_proto.a
# libdeflate encodes codec 1 (raw DEFLATE); zstd (codec 2) and zlib come from PKGS.
PKG_LIBS       += -ldeflate

BINS    += $(PROTO_LIB) $(BUILD)/test_proto $(BUILD)/gen_vectors
TESTS   += test-proto test-proto-asan test-proto-js test-proto-valgrind
BENCHES += bench-codec

$(PROTO_LIB): $(patsubst %.c,$(BUILD)/obj/%.o,$(PROTO_SRCS))
	@mkdir -p $(dir $@)
	rm -f $@ && ar rcs $@ $^
$(PROTO_SAN_LIB): $(patsubst %.c,$(BUILD)/san/%.o,$(PROTO_SRCS))
	@mkdir -p $(dir $@)
	rm -f $@ && ar rcs $@ $^

$(BUILD)/test_proto: $(BUILD)/obj/tests/test_proto.o $(PROTO_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/san/test_proto: $(BUILD)/san/tests/test_proto.o $(PROTO_SAN_LIB)
	$(CC) $(CFLAGS) $(SAN_FLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/gen_vectors: $(BUILD)/obj/proto/tools/gen_vectors.o $(PROTO_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)

.PHONY: test-proto test-proto-asan test-proto-valgrind test-proto-js proto-vectors bench-codec
test-proto: $(BUILD)/test_proto $(BUILD)/gen_vectors
	$(BUILD)/test_proto proto/vectors
	@# the checked-in vectors must be exactly what today's encoder writes
	@rm -rf $(BUILD)/vectors-regen && mkdir -p $(BUILD)/vectors-regen && $(BUILD)/gen_vectors $(BUILD)/vectors-regen >/dev/null
	@diff -r --exclude=control proto/vectors $(BUILD)/vectors-regen >/dev/null || { echo "proto/vectors is stale: run make proto-vectors"; exit 1; }
	set -o pipefail; python3 proto/tools/ref_decode.py proto/vectors | tail -1
test-proto-asan: $(BUILD)/san/test_proto
	ASAN_OPTIONS=detect_leaks=1 $(BUILD)/san/test_proto proto/vectors
# The C tests under valgrind: zero errors, zero definite leaks (~40 s of CPU: the 60 s temporal stream).
test-proto-valgrind: $(BUILD)/test_proto
	valgrind -q --error-exitcode=1 --leak-check=full --errors-for-leak-kinds=definite $(BUILD)/test_proto proto/vectors
test-proto-js: $(BUILD)/wasm/oc_kernels.wasm
	node --test tests/proto_js.test.mjs tests/proto_js_inflate.test.mjs tests/proto_js_browser.test.mjs
proto-vectors: $(BUILD)/gen_vectors
	$(BUILD)/gen_vectors proto/vectors

# The benchmark uses the real simulation when its library exists, else a
# synthetic Phillips-like field; zfp is a benchmark-only peer.
BENCH_OCEAN := $(if $(wildcard server/sim/ocean.c),1,)
$(BUILD)/bench_codec: bench/bench_codec.c bench/bench_time.h $(PROTO_LIB) $(if $(BENCH_OCEAN),$(BUILD)/libocean.a)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(INC) $(PKG_CFLAGS) $(if $(BENCH_OCEAN),-DHAVE_OCEAN) -o $@ $(filter-out %.h,$^) -lzfp -lfftw3f $(PKG_LIBS)
bench-codec: $(BUILD)/bench_codec
	@mkdir -p $(BUILD)/bench_frames
	@$(BUILD)/bench_codec --frames $(BUILD)/bench_frames
	@node proto/js/bench_decode.mjs $(BUILD)/bench_frames

# The codec's inner loops (range scan, quantise, prediction, escape packing)
# are written to auto-vectorise; -O3 turns that on for proto/ objects only
# (sanitizer objects keep SAN_FLAGS' -O1, which comes later on the command line).
$(BUILD)/obj/proto/%.o: CFLAGS += -O3
# The temporal predictor's row loop vectorises only when GCC may assume FP
# operations do not trap (we never enable FP traps). No value changes: it
# does not allow reassociation or contraction, so results stay bit-exact.
$(BUILD)/obj/proto/c/oc_temporal.o: CFLAGS += -fno-trapping-math
