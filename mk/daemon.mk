# mk/daemon.mk — the oceand daemon: binary, integration tests, load bench, `make run`.

# Every .c file of the daemon's folders (the simulation library and the
# cluster transport are libraries of their own: mk/sim.mk, mk/cluster.mk).
DAEMON_DIRS := base control config query tick net roles
DAEMON_SRC  := server/main.c $(sort $(foreach d,$(DAEMON_DIRS),$(wildcard server/$(d)/*.c)))
# The parts that tests and fuzzers link on their own.
BASE_OBJ    := $(patsubst %.c,$(BUILD)/obj/%.o,$(wildcard server/base/*.c))
CONTROL_OBJ := $(patsubst %.c,$(BUILD)/obj/%.o,$(wildcard server/control/*.c))
CONFIG_OBJ  := $(patsubst %.c,$(BUILD)/obj/%.o,$(wildcard server/config/*.c))
DAEMON_OBJ := $(DAEMON_SRC:%.c=$(BUILD)/obj/%.o)
DAEMON_SAN_OBJ := $(DAEMON_SRC:%.c=$(BUILD)/san/%.o)
OCEAN_LIB ?= $(BUILD)/libocean.a
OCEAN_SAN_LIB ?= $(BUILD)/san/libocean.a
PROTO_LIB ?= $(BUILD)/liboc_proto.a
PROTO_SAN_LIB ?= $(BUILD)/san/liboc_proto.a

BINS += $(BUILD)/oceand
TESTS += test-daemon test-daemon-asan test-daemon-valgrind
BENCHES += bench-load bench-capacity bench-layer-flood bench-bodies bench-load-bodies

# The cluster roles (--role sim|edge) link the NATS transport (mk/cluster.mk).
$(BUILD)/oceand: $(DAEMON_OBJ) $(OCEAN_LIB) $(PROTO_LIB) $(CLUSTER_LIB)
	$(CC) $(CFLAGS) -o $@ $(DAEMON_OBJ) $(OCEAN_LIB) $(CLUSTER_LIB) $(PROTO_LIB) $(PKG_LIBS) $(CLUSTER_LIBS)

$(BUILD)/san/oceand: $(DAEMON_SAN_OBJ) $(OCEAN_SAN_LIB) $(PROTO_SAN_LIB) $(CLUSTER_SAN_LIB)
	$(CC) $(CFLAGS) $(SAN_FLAGS) -o $@ $(DAEMON_SAN_OBJ) $(OCEAN_SAN_LIB) $(CLUSTER_SAN_LIB) $(PROTO_SAN_LIB) $(PKG_LIBS) $(CLUSTER_LIBS)

# Unit test of the pure control module (parse/validate), and the frame checker
# the integration tests use to decode frames and compare with the library.
$(BUILD)/test_control: $(BUILD)/obj/tests/daemon/test_control.o $(CONTROL_OBJ) \
                       $(BUILD)/obj/server/tick/capacity.o $(CONFIG_OBJ) $(BASE_OBJ) $(OCEAN_LIB) $(PROTO_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/san/test_control: $(BUILD)/san/tests/daemon/test_control.o $(CONTROL_OBJ:$(BUILD)/obj/%=$(BUILD)/san/%) \
                       $(BUILD)/san/server/tick/capacity.o $(CONFIG_OBJ:$(BUILD)/obj/%=$(BUILD)/san/%) $(BASE_OBJ:$(BUILD)/obj/%=$(BUILD)/san/%) $(OCEAN_SAN_LIB) $(PROTO_SAN_LIB)
	$(CC) $(CFLAGS) $(SAN_FLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/test_seq_guard: $(BUILD)/obj/tests/daemon/test_seq_guard.o $(BUILD)/obj/server/roles/seq_guard.o
	$(CC) $(CFLAGS) -o $@ $^
# The tick's pure steps may be tested from inside the folder (its internal header).
$(BUILD)/obj/tests/daemon/test_frame_want.o: INC += -Iserver/tick
$(BUILD)/test_frame_want: $(BUILD)/obj/tests/daemon/test_frame_want.o $(BUILD)/obj/server/tick/frame_want.o $(BUILD)/obj/server/tick/capacity.o \
                        $(CONTROL_OBJ) $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/frame_check: $(BUILD)/obj/tests/daemon/frame_check.o $(CONTROL_OBJ) $(OCEAN_LIB) $(PROTO_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)

# (prerequisites are expanded where a rule is read: the whole list comes first)
DAEMON_TEST_DEPS := $(BUILD)/test_control $(BUILD)/frame_check $(BUILD)/test_probe $(BUILD)/query_ref $(BUILD)/test_seq_guard \
                    $(BUILD)/test_frame_want

# Valgrind for the unit test: zero errors and zero definite leaks (~5 s).
VALGRIND ?= valgrind -q --error-exitcode=1 --leak-check=full --errors-for-leak-kinds=definite

.PHONY: test-daemon test-daemon-asan test-daemon-valgrind bench-load bench-capacity bench-layer-flood run
test-daemon: $(BUILD)/oceand $(BUILD)/ocean-tap $(DAEMON_TEST_DEPS)
	$(BUILD)/test_control
	$(BUILD)/test_seq_guard
	$(BUILD)/test_frame_want
	/usr/bin/python3 tests/daemon/test_daemon.py --oceand $(BUILD)/oceand --frame-check $(BUILD)/frame_check
	/usr/bin/python3 tests/daemon/test_temporal.py --oceand $(BUILD)/oceand --frame-check $(BUILD)/frame_check
	$(BUILD)/test_probe
	/usr/bin/python3 tests/daemon/test_query.py --oceand $(BUILD)/oceand --frame-check $(BUILD)/frame_check --query-ref $(BUILD)/query_ref
	/usr/bin/python3 tests/daemon/test_render.py --oceand $(BUILD)/oceand --frame-check $(BUILD)/frame_check
	/usr/bin/python3 tests/daemon/test_bodies.py --oceand $(BUILD)/oceand
	/usr/bin/python3 tests/daemon/test_sea.py --oceand $(BUILD)/oceand --tap $(BUILD)/ocean-tap

# The measured-sea part of test-daemon alone (~15 s): the `sea` message against a real daemon.
.PHONY: test-daemon-sea
test-daemon-sea: $(BUILD)/oceand $(BUILD)/ocean-tap
	/usr/bin/python3 tests/daemon/test_sea.py --oceand $(BUILD)/oceand --tap $(BUILD)/ocean-tap

# Same integration tests against an ASan+UBSan build (slower: frames at a lower N).
test-daemon-asan: $(BUILD)/san/oceand $(BUILD)/san/test_control $(BUILD)/ocean-tap $(DAEMON_TEST_DEPS)
	$(BUILD)/san/test_control
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  /usr/bin/python3 tests/daemon/test_daemon.py --oceand $(BUILD)/san/oceand --frame-check $(BUILD)/frame_check --sanitized
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  /usr/bin/python3 tests/daemon/test_temporal.py --oceand $(BUILD)/san/oceand --frame-check $(BUILD)/frame_check --sanitized
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  /usr/bin/python3 tests/daemon/test_query.py --oceand $(BUILD)/san/oceand --frame-check $(BUILD)/frame_check \
	  --query-ref $(BUILD)/query_ref --sanitized
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  /usr/bin/python3 tests/daemon/test_render.py --oceand $(BUILD)/san/oceand --frame-check $(BUILD)/frame_check --sanitized
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  /usr/bin/python3 tests/daemon/test_bodies.py --oceand $(BUILD)/san/oceand --sanitized
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  /usr/bin/python3 tests/daemon/test_sea.py --oceand $(BUILD)/san/oceand --tap $(BUILD)/ocean-tap --sanitized

test-daemon-valgrind: $(BUILD)/test_control
	$(VALGRIND) $(BUILD)/test_control

bench-load: $(BUILD)/oceand $(BUILD)/load_client
	/usr/bin/python3 bench/load.py --oceand $(BUILD)/oceand --load-client $(BUILD)/load_client $(BENCH_LOAD_ARGS)

# The capacity rows (docs/daemon.md, "Capacity figures"): N = 512 and 1024 six fields, 1024 and 2048 h/dx/dz, 2048 height,
# 256 with 200 clients; three runs each, then a median line per row (~4 min).
bench-capacity: $(BUILD)/oceand $(BUILD)/load_client
	/usr/bin/python3 bench/load.py --capacity --oceand $(BUILD)/oceand --load-client $(BUILD)/load_client $(BENCH_CAPACITY_ARGS)

# Many distinct layers against the encode budget (N = 512, 25 viewers asking for every field x LOD x bound):
# admitted/refused, observer frames/s, overruns, encode/tick time, RSS; one JSON line (~15 s).
bench-layer-flood: $(BUILD)/oceand
	/usr/bin/python3 bench/layer_flood.py --oceand $(BUILD)/oceand

# Floating bodies' cost on the tick: a real daemon at N = 256 with 64 bodies launched against none,
# the tick and bodies-step durations from /metrics, JSON lines with the ratio (~1 min).
.PHONY: bench-bodies
bench-bodies: $(BUILD)/oceand
	/usr/bin/python3 bench/bodies.py --oceand $(BUILD)/oceand $(BENCH_BODIES_ARGS)

# 200 viewers (N = 256, temporal, as bench-load's row) with 64 bodies floating, the powered ones
# under way: delivered share, overruns, tick and bodies-step time; one JSON line (~20 s).
.PHONY: bench-load-bodies
bench-load-bodies: $(BUILD)/oceand $(BUILD)/load_client
	/usr/bin/python3 bench/load.py --runs 256:200 --bodies 64 --no-query $(BENCH_LOAD_BODIES_ARGS)

run: deps
	@$(MAKE) --no-print-directory build-all
	@if [ ! -f $(BUILD)/web/index.html ]; then echo "run: no $(BUILD)/web/index.html, oceand serves a placeholder page"; fi
	@echo "run: open http://127.0.0.1:8080/ (Ctrl-C stops)"
	exec $(BUILD)/oceand --web-root $(BUILD)/web $(OCEAND_ARGS)

$(BUILD)/load_client: $(BUILD)/obj/bench/load_client.o
	$(CC) $(CFLAGS) -o $@ $^

# Point queries and probes (docs/query.md): the probe accuracy test and the exact
# reference the daemon tests compare `query_result` with.
$(BUILD)/test_probe: $(BUILD)/obj/tests/daemon/test_probe.o $(BUILD)/obj/server/query/probe.o $(CONTROL_OBJ) $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)
$(BUILD)/query_ref: $(BUILD)/obj/tests/daemon/query_ref.o $(CONTROL_OBJ) $(OCEAN_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(PKG_LIBS)

# The tree's shape (tests/layout/test_layout.py): main.c and folders in
# server/, no daemon file over 800 lines, no two files of one name, internal
# headers kept inside their folder, no parameter looked up by name.
TESTS += test-layout
.PHONY: test-layout
test-layout:
	/usr/bin/python3 tests/layout/test_layout.py .

# The docs and the code say what is true now: no diary of numbered work
# sessions and no issue-tracker numbers in docs, comments, strings, test
# names and make targets (tests/layout/test_wording.py has the patterns;
# it also proves it can fail).
TESTS += test-wording
.PHONY: test-wording
test-wording:
	/usr/bin/python3 tests/layout/test_wording.py .
