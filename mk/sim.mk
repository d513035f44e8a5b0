# mk/sim.mk — the simulation library (server/sim/: public headers in server/sim/include).
#   make build/libocean.a       the library (and build/san/libocean.a)
#   make test-sim               physics + FFT-vs-DFT suite (tests/test_ocean.c)
#   make test-sim-asan          the same suite built with ASan+UBSan
#   make test-sim-valgrind      a reduced run (OCEAN_TEST_QUICK=1) under valgrind
#   make test-sim-tsan          a reduced run under ThreadSanitizer (clang): the pool,
#                               and ocean_prepare on one thread while another steps
#   make bench-step             step / FFTW / DFT timings, JSON lines
# See docs/simulation.md.

# The library's archive carries the program's work pool (server/common/pool.c):
# the library runs on it, and the daemon links it from here.
SIM_SRCS      := $(wildcard server/sim/*.c) server/common/pool.c
OCEAN_LIB     := $(BUILD)/libocean.a
OCEAN_SAN_LIB := $(BUILD)/san/libocean.a
SIM_WISDOM    := $(BUILD)/fftw-wisdom

BINS    += $(OCEAN_LIB) $(BUILD)/test_ocean $(BUILD)/bench_step
TESTS   += test-sim test-sim-asan test-sim-valgrind test-sim-tsan
BENCHES += bench-step

$(OCEAN_LIB): $(patsubst %.c,$(BUILD)/obj/%.o,$(SIM_SRCS))
	@mkdir -p $(dir $@)
	rm -f $@ && ar rcs $@ $^
$(OCEAN_SAN_LIB): $(patsubst %.c,$(BUILD)/san/%.o,$(SIM_SRCS))
	@mkdir -p $(dir $@)
	rm -f $@ && ar rcs $@ $^

# The per-mode loops are written to auto-vectorise: -O3 for these objects
# (sanitizer objects keep SAN_FLAGS' -O1, which comes later on the line).
$(patsubst %.c,$(BUILD)/obj/%.o,$(SIM_SRCS)): CFLAGS += -O3

# The library's own tests and benchmark may look inside (ocean_internal.h).
$(BUILD)/obj/tests/test_ocean.o $(BUILD)/san/tests/test_ocean.o $(BUILD)/obj/bench/bench_step.o: \
  INC := -Iserver/sim/include -Iserver/sim -Iserver/common

$(BUILD)/test_ocean: $(BUILD)/obj/tests/test_ocean.o $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/san/test_ocean: $(BUILD)/san/tests/test_ocean.o $(OCEAN_SAN_LIB)
	$(CC) $(CFLAGS) $(SAN_FLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/bench_step: $(BUILD)/obj/bench/bench_step.o $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)

# ThreadSanitizer build: clang, the whole library (with the work pool) compiled in. target_clones
# is compiled out (TSan crashes inside the ifunc resolvers, which run before
# it is initialised); FFTW itself is not instrumented (one thread per plan).
$(BUILD)/tsan/test_ocean: tests/test_ocean.c $(SIM_SRCS) $(wildcard server/sim/*.h server/sim/include/*.h server/common/*.h)
	@mkdir -p $(dir $@)
	clang -std=c11 -D_GNU_SOURCE -g -O1 -fsanitize=thread $(WARN) '-Dtarget_clones(...)=unused' \
	  -Iserver/sim/include -Iserver/sim -Iserver/common tests/test_ocean.c $(SIM_SRCS) -o $@ -lfftw3f -lfftw3f_threads -lm -pthread

.PHONY: test-sim test-sim-asan test-sim-valgrind test-sim-tsan bench-step
# Tests plan with FFTW_ESTIMATE and no wisdom file: deterministic and quick.
test-sim: $(BUILD)/test_ocean
	$(BUILD)/test_ocean
test-sim-asan: $(BUILD)/san/test_ocean
	ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 $(BUILD)/san/test_ocean
test-sim-valgrind: $(BUILD)/test_ocean
	OCEAN_TEST_QUICK=1 valgrind -q --error-exitcode=1 --leak-check=full --show-possibly-lost=no \
	  --errors-for-leak-kinds=definite,indirect $(BUILD)/test_ocean
test-sim-tsan: $(BUILD)/tsan/test_ocean
	OCEAN_TEST_QUICK=1 TSAN_OPTIONS=halt_on_error=1:exitcode=66 $(BUILD)/tsan/test_ocean
# FFTW_MEASURE plans, cached in $(SIM_WISDOM) across runs.
bench-step: $(BUILD)/bench_step
	$(BUILD)/bench_step $(SIM_WISDOM)

# Point queries (server/sim/ocean_query.c): exact surface values at any (x, z).
#   make test-query             against a brute-force reference (tests/test_query.c)
#   make test-query-asan        the same with ASan+UBSan
#   make test-query-valgrind    a reduced run (OCEAN_TEST_QUICK=1) under valgrind
#   make bench-query            cost per point at N = 256 and 512, JSON lines
BINS    += $(BUILD)/test_query $(BUILD)/bench_query
TESTS   += test-query test-query-asan test-query-valgrind
BENCHES += bench-query
$(BUILD)/obj/tests/test_query.o $(BUILD)/san/tests/test_query.o $(BUILD)/obj/bench/bench_query.o: \
  INC := -Iserver/sim/include -Iserver/sim -Iserver/common
$(BUILD)/test_query: $(BUILD)/obj/tests/test_query.o $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/san/test_query: $(BUILD)/san/tests/test_query.o $(OCEAN_SAN_LIB)
	$(CC) $(CFLAGS) $(SAN_FLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/bench_query: $(BUILD)/obj/bench/bench_query.o $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
.PHONY: test-query test-query-asan test-query-valgrind bench-query
test-query: $(BUILD)/test_query
	$(BUILD)/test_query
test-query-asan: $(BUILD)/san/test_query
	ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 OCEAN_TEST_QUICK=1 $(BUILD)/san/test_query
test-query-valgrind: $(BUILD)/test_query
	OCEAN_TEST_QUICK=1 valgrind -q --error-exitcode=1 --leak-check=full --show-possibly-lost=no \
	  --errors-for-leak-kinds=definite,indirect $(BUILD)/test_query
bench-query: $(BUILD)/bench_query
	$(BUILD)/bench_query
# The query's per-mode sums are reductions: OpenMP's simd pragma (no
# runtime, no threads) lets them vectorise without -ffast-math.
$(BUILD)/obj/server/sim/ocean_query.o $(BUILD)/san/server/sim/ocean_query.o: CFLAGS += -fopenmp-simd

# Bodies (server/sim/bodies*.c): rigid bodies floating on the sea, no networking.
#   make test-bodies            physics against theory, determinism, the API (tests/test_bodies.c)
#   make test-bodies-asan       the same with ASan+UBSan
#   make test-bodies-valgrind   a reduced run (OCEAN_TEST_QUICK=1) under valgrind
#   make bench-bodies-step      us per body per 30 Hz tick, 64 bodies of mixed kinds, JSON lines
BINS    += $(BUILD)/test_bodies $(BUILD)/bench_bodies
TESTS   += test-bodies test-bodies-asan test-bodies-valgrind
BENCHES += bench-bodies-step
$(BUILD)/obj/tests/test_bodies.o $(BUILD)/san/tests/test_bodies.o $(BUILD)/obj/bench/bench_bodies.o: \
  INC := -Iserver/sim/include -Iserver/sim
$(BUILD)/test_bodies: $(BUILD)/obj/tests/test_bodies.o $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/san/test_bodies: $(BUILD)/san/tests/test_bodies.o $(OCEAN_SAN_LIB)
	$(CC) $(CFLAGS) $(SAN_FLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/bench_bodies: $(BUILD)/obj/bench/bench_bodies.o $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
.PHONY: test-bodies test-bodies-asan test-bodies-valgrind bench-bodies-step
test-bodies: $(BUILD)/test_bodies
	$(BUILD)/test_bodies
test-bodies-asan: $(BUILD)/san/test_bodies
	ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 $(BUILD)/san/test_bodies
test-bodies-valgrind: $(BUILD)/test_bodies
	OCEAN_TEST_QUICK=1 valgrind -q --error-exitcode=1 --leak-check=full --show-possibly-lost=no \
	  --errors-for-leak-kinds=definite,indirect $(BUILD)/test_bodies
bench-bodies-step: $(BUILD)/bench_bodies
	$(BUILD)/bench_bodies
# Measured seas (server/sim/sea_spectrum.c, sea_model.c): spectrum "measured" against its
# targets, measured from the simulated surface (tests/test_sea.c).
#   make test-sea               the whole suite, ~8 s (figures on every line)
#   make test-sea-asan          the same with ASan+UBSan
#   make test-sea-valgrind      a reduced run (OCEAN_TEST_QUICK=1) under valgrind
BINS    += $(BUILD)/test_sea
TESTS   += test-sea test-sea-asan test-sea-valgrind
$(BUILD)/obj/tests/test_sea.o $(BUILD)/san/tests/test_sea.o: INC := -Iserver/sim/include -Itests
$(BUILD)/test_sea: $(BUILD)/obj/tests/test_sea.o $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/san/test_sea: $(BUILD)/san/tests/test_sea.o $(OCEAN_SAN_LIB)
	$(CC) $(CFLAGS) $(SAN_FLAGS) -o $@ $^ $(PKG_LIBS)
.PHONY: test-sea test-sea-asan test-sea-valgrind
test-sea: $(BUILD)/test_sea
	$(BUILD)/test_sea
test-sea-asan: $(BUILD)/san/test_sea
	ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 OCEAN_TEST_QUICK=1 $(BUILD)/san/test_sea
test-sea-valgrind: $(BUILD)/test_sea
	OCEAN_TEST_QUICK=1 valgrind -q --error-exitcode=1 --leak-check=full --show-possibly-lost=no \
	  --errors-for-leak-kinds=definite,indirect $(BUILD)/test_sea
# Wakes (server/sim/wakes.c): the layer of dynamic waves bodies make, against theory.
#   make test-wakes             Kelvin angle, transverse wavelength, the Fr^-1 narrowing,
#                               finite depth, a drop's ring, stability, regions (tests/test_wakes.c)
#   make test-wakes-asan        the same with ASan+UBSan, a reduced run (OCEAN_TEST_QUICK=1)
#   make test-wakes-valgrind    a reduced run under valgrind: the groups that are not large patterns
#   make bench-wakes            the layer's step for 8 moving boats at 30 Hz, JSON lines
BINS    += $(BUILD)/test_wakes $(BUILD)/bench_wakes
TESTS   += test-wakes test-wakes-asan test-wakes-valgrind
BENCHES += bench-wakes
$(BUILD)/obj/tests/test_wakes.o $(BUILD)/san/tests/test_wakes.o $(BUILD)/obj/bench/bench_wakes.o: \
  INC := -Iserver/sim/include -Itests
$(BUILD)/test_wakes: $(BUILD)/obj/tests/test_wakes.o $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/san/test_wakes: $(BUILD)/san/tests/test_wakes.o $(OCEAN_SAN_LIB)
	$(CC) $(CFLAGS) $(SAN_FLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/bench_wakes: $(BUILD)/obj/bench/bench_wakes.o $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
.PHONY: test-wakes test-wakes-asan test-wakes-valgrind bench-wakes
test-wakes: $(BUILD)/test_wakes
	$(BUILD)/test_wakes
test-wakes-asan: $(BUILD)/san/test_wakes
	ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 OCEAN_TEST_QUICK=1 $(BUILD)/san/test_wakes
test-wakes-valgrind: $(BUILD)/test_wakes
	OCEAN_TEST_QUICK=1 OCEAN_TEST_ONLY=test_energy,test_circling,test_regions,test_foam,test_displacement,test_api valgrind -q --error-exitcode=1 --leak-check=full --show-possibly-lost=no \
	  --errors-for-leak-kinds=definite,indirect $(BUILD)/test_wakes
bench-wakes: $(BUILD)/bench_wakes
	$(BUILD)/bench_wakes
