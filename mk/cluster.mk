# mk/cluster.mk — the cluster transport: server/cluster/, one
# simulation and many edge daemons over NATS. See docs/scaling.md.
#   make build/libcluster.a      the module (and build/san/libcluster.a)
#   make test-cluster            unit test (formats, assembler, demand expiry), normal and ASan+UBSan,
#                                then the NATS integration test (starts its own nats-server on
#                                127.0.0.1, kills and restarts it), normal and ASan+UBSan
#   make test-cluster-valgrind   the unit test under valgrind
#   make test-cluster-roles      oceand --role sim|edge end to end (nats-server, a sim, edges,
#                                WebSocket clients; kill/restart cycles), and the same against
#                                the ASan+UBSan daemon (fewer cycles)
#   make test-cluster-durable    no acknowledged set lost by a kill -9 of a sim, NATS, an edge or
#                                --role all; versions never back; the standby sim takes over
#                                (nats-server with JetStream, its store in the test's folder)
#   make test-cluster-bodies     floating bodies through edges (launch, steer, claim; the same
#                                record on the same seq on every edge) and across a take-over
# oceand links the module for --role sim|edge (mk/daemon.mk); only the role
# glue (server/roles/) sees server/cluster/.

CLUSTER_SRCS    := $(sort $(wildcard server/cluster/*.c))
CLUSTER_LIB     := $(BUILD)/libcluster.a
CLUSTER_SAN_LIB := $(BUILD)/san/libcluster.a
CLUSTER_LIBS     = $(shell pkg-config --libs libnats 2>/dev/null || echo -lnats)
PROTO_LIB       ?= $(BUILD)/liboc_proto.a
PROTO_SAN_LIB   ?= $(BUILD)/san/liboc_proto.a

BINS  += $(CLUSTER_LIB) $(BUILD)/test_cluster_msg $(BUILD)/test_cluster_nats
TESTS += test-cluster test-cluster-valgrind test-cluster-roles test-cluster-durable test-cluster-bodies

# The module sees only its own folder and the protocol's header: no sim
# internals, no daemon headers, no libwebsockets.
$(patsubst %.c,$(BUILD)/obj/%.o,$(CLUSTER_SRCS)) $(patsubst %.c,$(BUILD)/san/%.o,$(CLUSTER_SRCS)): \
  INC := -Iserver/cluster -Iproto/c

$(CLUSTER_LIB): $(patsubst %.c,$(BUILD)/obj/%.o,$(CLUSTER_SRCS))
	@mkdir -p $(dir $@)
	rm -f $@ && ar rcs $@ $^
$(CLUSTER_SAN_LIB): $(patsubst %.c,$(BUILD)/san/%.o,$(CLUSTER_SRCS))
	@mkdir -p $(dir $@)
	rm -f $@ && ar rcs $@ $^

$(BUILD)/test_cluster_msg: $(BUILD)/obj/tests/cluster/test_cluster_msg.o $(CLUSTER_LIB) $(PROTO_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(CLUSTER_LIBS) $(PKG_LIBS)
$(BUILD)/san/test_cluster_msg: $(BUILD)/san/tests/cluster/test_cluster_msg.o $(CLUSTER_SAN_LIB) $(PROTO_SAN_LIB)
	$(CC) $(CFLAGS) $(SAN_FLAGS) -o $@ $^ $(CLUSTER_LIBS) $(PKG_LIBS)
$(BUILD)/test_cluster_nats: $(BUILD)/obj/tests/cluster/test_cluster_nats.o $(CLUSTER_LIB) $(PROTO_LIB)
	$(CC) $(CFLAGS) -o $@ $^ $(CLUSTER_LIBS) $(PKG_LIBS)
$(BUILD)/san/test_cluster_nats: $(BUILD)/san/tests/cluster/test_cluster_nats.o $(CLUSTER_SAN_LIB) $(PROTO_SAN_LIB)
	$(CC) $(CFLAGS) $(SAN_FLAGS) -o $@ $^ $(CLUSTER_LIBS) $(PKG_LIBS)

.PHONY: test-cluster test-cluster-valgrind
test-cluster: $(BUILD)/test_cluster_msg $(BUILD)/san/test_cluster_msg $(BUILD)/test_cluster_nats $(BUILD)/san/test_cluster_nats
	$(BUILD)/test_cluster_msg
	ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 $(BUILD)/san/test_cluster_msg
	$(BUILD)/test_cluster_nats
	ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 $(BUILD)/san/test_cluster_nats
test-cluster-valgrind: $(BUILD)/test_cluster_msg
	valgrind -q --error-exitcode=1 --leak-check=full --errors-for-leak-kinds=definite $(BUILD)/test_cluster_msg

CLUSTER_ROLES_CYCLES ?= 5
.PHONY: test-cluster-roles
test-cluster-roles: $(BUILD)/oceand $(BUILD)/san/oceand
	/usr/bin/python3 tests/cluster/test_cluster_roles.py --oceand $(BUILD)/oceand --cycles $(CLUSTER_ROLES_CYCLES)
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  /usr/bin/python3 tests/cluster/test_cluster_roles.py --oceand $(BUILD)/san/oceand --cycles 2 --recovery-s 6

CLUSTER_DURABLE_CYCLES ?= 3
.PHONY: test-cluster-durable
test-cluster-durable: $(BUILD)/oceand $(BUILD)/san/oceand
	/usr/bin/python3 tests/cluster/test_cluster_durable.py --oceand $(BUILD)/oceand --cycles $(CLUSTER_DURABLE_CYCLES)
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  /usr/bin/python3 tests/cluster/test_cluster_durable.py --oceand $(BUILD)/san/oceand --cycles 2

# Floating bodies through edges and across a standby's take-over (~25 s, ~40 s under ASan).
.PHONY: test-cluster-bodies
test-cluster-bodies: $(BUILD)/oceand $(BUILD)/san/oceand
	/usr/bin/python3 tests/cluster/test_cluster_bodies.py --oceand $(BUILD)/oceand
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  /usr/bin/python3 tests/cluster/test_cluster_bodies.py --oceand $(BUILD)/san/oceand

# 1 sim + 1, 2, 3 edges + nats-server on this machine vs --role all (docs/scaling.md).
BENCHES += bench-cluster
.PHONY: bench-cluster
bench-cluster: $(BUILD)/oceand $(BUILD)/load_client
	/usr/bin/python3 bench/cluster.py --oceand $(BUILD)/oceand --load-client $(BUILD)/load_client $(BENCH_CLUSTER_ARGS)

# Standby take-over gap (median of 5 kill -9 of the active sim) and acknowledged sets lost.
BENCHES += bench-cluster-failover
.PHONY: bench-cluster-failover
bench-cluster-failover: $(BUILD)/oceand
	/usr/bin/python3 bench/cluster_failover.py --oceand $(BUILD)/oceand $(BENCH_FAILOVER_ARGS)

# nats-server (installed by make deps if missing) + two sims + two edges on loopback.
.PHONY: run-cluster
run-cluster: deps
	@$(MAKE) --no-print-directory build-all
	@if [ ! -f $(BUILD)/web/index.html ]; then echo "run-cluster: no $(BUILD)/web/index.html, the edges serve a placeholder page"; fi
	exec scripts/run-cluster.sh
