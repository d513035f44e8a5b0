# mk/cluster.mk — the cluster transport (issue 12): server/cluster/, one
# simulation and many edge daemons over NATS. See docs/scaling.md.
#   make build/libcluster.a      the module (and build/san/libcluster.a)
#   make test-cluster            unit test (formats, assembler, demand expiry), normal and ASan+UBSan,
#                                then the NATS integration test (starts its own nats-server on
#                                127.0.0.1, kills and restarts it), normal and ASan+UBSan
#   make test-cluster-valgrind   the unit test under valgrind
# libnats is linked only into cluster targets until the daemon uses it.

CLUSTER_SRCS    := $(sort $(wildcard server/cluster/*.c))
CLUSTER_LIB     := $(BUILD)/libcluster.a
CLUSTER_SAN_LIB := $(BUILD)/san/libcluster.a
CLUSTER_LIBS     = $(shell pkg-config --libs libnats 2>/dev/null || echo -lnats)
PROTO_LIB       ?= $(BUILD)/liboc_proto.a
PROTO_SAN_LIB   ?= $(BUILD)/san/liboc_proto.a

BINS  += $(CLUSTER_LIB) $(BUILD)/test_cluster_msg $(BUILD)/test_cluster_nats
TESTS += test-cluster test-cluster-valgrind

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
